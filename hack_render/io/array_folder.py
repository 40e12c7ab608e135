"""Folders of named arrays for the disk caches: one ``.npy`` a name and an ``index.json``
(the names and a JSON-ready ``info`` dict), read without pickle and written atomically (a
temporary folder renamed). The model file's cache (:mod:`hack_render.geometry.model_file`)
and the appearance caches (:mod:`appearance.cache`) keep their entries this way.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np


def cache_base() -> Path:
    """``$XDG_CACHE_HOME/hack-render`` (``~/.cache/hack-render`` when it is not set)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")) / "hack-render"


def read_array_folder(folder: Path, mmap: bool = False
                      ) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
    """(arrays, info) of an entry, or None when it is absent, partial or damaged.
    ``mmap``: the arrays are mapped copy-on-write (read as they are used). A hit touches the
    folder, so that :func:`write_array_folder` keeps the newest entries."""
    try:
        index = json.loads((folder / "index.json").read_text())
        arrays = {k: np.load(folder / f"{k}.npy", mmap_mode="c" if mmap else None,
                             allow_pickle=False) for k in index["keys"]}
        info = index["info"]
        os.utime(folder)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return arrays, info


def write_array_folder(folder: Path, arrays: dict[str, Any], info: dict[str, Any],
                       keep: int, siblings: str = "*") -> None:
    """Write an entry to ``folder`` (a damaged one there replaced), then drop all but the
    newest ``keep`` of the folders beside it that match the glob ``siblings``. Raises
    OSError (a full disk, a read-only cache): the caller decides what that costs."""
    tmp = folder.with_name(f".{folder.name}.{os.getpid()}.tmp")
    try:
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for k, v in arrays.items():
            np.save(tmp / f"{k}.npy", np.asarray(v), allow_pickle=False)
        (tmp / "index.json").write_text(json.dumps({"keys": sorted(arrays), "info": info}))
        shutil.rmtree(folder, ignore_errors=True)
        os.replace(tmp, folder)
        entries = sorted((p for p in folder.parent.glob(siblings)
                          if p.is_dir() and not p.name.startswith(".")),
                         key=lambda p: p.stat().st_mtime_ns, reverse=True)
        for old in entries[keep:]:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
