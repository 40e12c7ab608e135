"""The fit's camera model: OpenCV pinhole with square pixels and the principal point at
the photo's centre; the camera looks along world -Z at the face (``R0 = diag(1, -1,
-1)``); its translation, focal length and the head's pose are fitted. Focal lengths are
in pixels; a 35 mm-equivalent focal spans ``SENSOR_MM`` over the photo's long side."""

from __future__ import annotations

import torch

R0 = torch.tensor([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
SENSOR_MM = 36.0
#: the focal prior's std of log focal length about camera.focal_mm_prior (no focal of the photo's)
FOCAL_LOG_SIGMA = 0.35
#: the same about the photo's own focal length (EXIF or --focal-mm): ~5 %, a zoom lens's rounding
PHOTO_FOCAL_LOG_SIGMA = 0.05


def focal_prior_px(camera_cfg, photo) -> tuple[float, float, str]:
    """(centre in pixels, std of log focal, source) of a photo's focal-length prior: the
    photo's own 35 mm-equivalent focal (EXIF or --focal-mm) when it has one and
    ``camera.use_photo_focal``, else ``camera.focal_mm_prior``; 36 mm spans the long
    side. ``camera_cfg``: :class:`~hack_render.fit.config.CameraConfig`."""
    c = camera_cfg
    side = max(photo.width, photo.height) / SENSOR_MM
    if c.use_photo_focal and photo.focal_mm:
        return photo.focal_mm * side, PHOTO_FOCAL_LOG_SIGMA, photo.focal_source or "photo"
    return c.focal_mm_prior * side, FOCAL_LOG_SIGMA, "prior"
