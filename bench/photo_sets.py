"""The real photos of ``bench_real_photos.py``: the openly licensed portraits in the
installed packages, and (``--more-photos``) the test photos in face_recognition 1.3.0's
source distribution, read from its archive (see ``bench_real_photos.py``'s docstring)."""

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
