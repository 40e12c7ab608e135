"""``.npz`` files of named arrays, written atomically (:func:`hack_render.io.atomic_path`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hack_render.io import atomic_path


def write_npz(path: str | Path, arrays: dict[str, Any], compressed: bool = False) -> Path:
    """Write named arrays as ``.npz`` (``np.savez``, or ``np.savez_compressed``) atomically
    (:func:`atomic_path`); returns ``path``. Written through a file object, so NumPy adds
    no ``.npz`` to a path that lacks it."""
    save = np.savez_compressed if compressed else np.savez
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        save(f, **arrays)
    return Path(path)
