"""Arrays that are pure functions of files and code, kept on disk between processes.

A dataset's start-up made the same arrays in every process: the appearance model's
validated arrays (~0.4 CPU s to unpack the shipped file), the subject projector's
operators (~0.3 s) and the generator's atlas precomputation (~0.25 s, with scipy.spatial's
import). :func:`cached_arrays` keeps such arrays in
``$XDG_CACHE_HOME/hack-render/appearance/<kind>-<hash>/`` (``~/.cache`` by default), one
``.npy`` each and an ``index.json``, named by the sha256 of what they are a function of
(the caller's ``key``: input files' identity, :func:`source_key` of the code that makes
them); later processes load them without pickle. The arrays are the same bits either
way. An entry that cannot be read is made again, one that cannot be written costs only
the time; the newest :data:`CACHE_KEEP` of each kind are kept; ``HACK_RENDER_NO_CACHE=1``
turns the cache off. NumPy only.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hack_render.io.array_folder import cache_base, read_array_folder, write_array_folder

#: Entries kept per kind (the newest)
CACHE_KEEP = 4
_CACHE_FORMAT = 1

Made = tuple[dict[str, np.ndarray], dict]


def file_key(path) -> list:
    """What identifies a file's content: its resolved path, size and modification time."""
    p = Path(path).resolve()
    st = p.stat()
    return [str(p), st.st_size, st.st_mtime_ns]


def source_key(*paths) -> str:
    """sha256 of source files (the code that makes an entry), for a ``key``."""
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def cache_root() -> Path | None:
    """The cache folder (None when ``HACK_RENDER_NO_CACHE`` is set)."""
    if os.environ.get("HACK_RENDER_NO_CACHE", "") not in ("", "0"):
        return None
    return cache_base() / "appearance"


def cached_arrays(kind: str, key: list, make: Callable[[], Made], mmap: bool = False) -> Made:
    """``make()``'s (arrays, JSON-ready dict), kept on disk by ``kind`` and ``key`` (JSON-ready:
    everything they are a function of). ``mmap``: later calls map the arrays copy-on-write
    (large arrays read as they are used) instead of reading them."""
    root = cache_root()
    if root is None:
        return make()
    digest = hashlib.sha256(json.dumps([_CACHE_FORMAT, kind, key]).encode()).hexdigest()
    folder = root / f"{kind}-{digest[:32]}"
    hit = read_array_folder(folder, mmap=mmap)
    if hit is not None:
        return hit
    arrays, extra = make()  # absent, partial or damaged: made again
    try:
        write_array_folder(folder, arrays, extra, CACHE_KEEP, siblings=f"{kind}-*")
    except OSError:  # a read-only or full cache: the next process makes them again
        pass
    return arrays, extra
