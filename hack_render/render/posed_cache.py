"""A disk cache of posed meshes for `hack-render render`, so a repeated render skips
importing torch and evaluating the geometry model (1.8 of its ~4 CPU s at 256 px).

The key is everything the posed mesh depends on, as the user gave it: the pose flags'
text, the parameter file's and the model file's identity (path, size, modification
time), the limits policy, and the source code of the geometry package and of
``render.parts`` (so an edit to the model's code never reuses an old mesh). What posing
printed (limit warnings) is stored with the mesh and printed again on a hit.

Files: ``$XDG_CACHE_HOME/hack-render/posed/<key>.npz`` (``~/.cache`` by default), the
newest :data:`KEEP` kept, loaded without pickle; ``HACK_RENDER_NO_CACHE=1`` turns the
cache off. A file that cannot be read is ignored and rewritten.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import sys
from collections.abc import Callable
from contextlib import redirect_stderr, suppress
from pathlib import Path

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry import default_model_path
from hack_render.io.npz import write_npz
from hack_render.render.parts import Topology

#: How many posed meshes are kept (~2 MB each).
KEEP = 16
FORMAT = 1
ENV_OFF = "HACK_RENDER_NO_CACHE"


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hack-render" / "posed"


def _identity(path) -> list | None:
    if path is None:
        return None
    p = Path(path).expanduser()
    try:
        st = p.stat()
    except OSError:
        return [str(p)]  # missing: posing raises its own clear error, nothing is cached
    return [str(p.resolve()), st.st_size, st.st_mtime_ns]


def _code_digest() -> str:
    """sha256 of the geometry package's and ``render/parts.py``'s source."""
    root = Path(__file__).resolve().parents[1]
    files = sorted((root / "geometry").glob("*.py")) + [root / "render" / "parts.py"]
    h = hashlib.sha256()
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def key(inputs: dict, model_path) -> str:
    """The cache key of a posed mesh: ``inputs`` (the pose flags and options as given,
    JSON-serialisable; paths among them under keys ending in ``_file``) and the model."""
    doc = {"format": FORMAT, "code": _code_digest(),
           "model": _identity(model_path if model_path is not None else default_model_path()),
           "inputs": {k: (_identity(v) if k.endswith("_file") else v)
                      for k, v in sorted(inputs.items())}}
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def posed(inputs: dict, model_path, compute: Callable[[], tuple[Topology, np.ndarray]]
          ) -> tuple[Topology, np.ndarray]:
    """(topology, vertices) from the cache, else from ``compute()`` (stored, with what it
    printed on stderr, for the next call)."""
    if os.environ.get(ENV_OFF, "") not in ("", "0"):
        return compute()
    k = key(inputs, model_path)
    path = cache_dir() / f"{k}.npz"
    hit = _load(path)
    if hit is not None:
        topo, verts, printed = hit
        if printed:
            sys.stderr.write(printed)
        with suppress(OSError):  # a read-only cache still serves; it just ages
            os.utime(path)  # most recently used
        return topo, verts
    buf = io.StringIO()
    with redirect_stderr(_Tee(sys.stderr, buf)):
        topo, verts = compute()
    _store(path, topo, verts, buf.getvalue())
    return topo, verts


def _load(path: Path):
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            topo = Topology(z["faces"], z["uvs"], z["uv_faces"], z["face_material"],
                            tuple(str(n) for n in z["material_names"]),
                            z["rest"] if "rest" in z.files else None)
            return topo, z["vertices"], str(z["printed"])
    except (OSError, KeyError, ValueError):
        return None


def _store(path: Path, topo: Topology, verts: np.ndarray, printed: str) -> None:
    try:
        write_npz(path, dict(faces=topo.faces, uvs=topo.uvs, uv_faces=topo.uv_faces,
                             face_material=topo.face_material,
                             material_names=np.array(topo.material_names, dtype=str),
                             vertices=np.asarray(verts), printed=np.array(printed),
                             **({} if topo.rest is None else {"rest": np.asarray(topo.rest)})))
        old = sorted(path.parent.glob("*.npz"), key=lambda p: p.stat().st_mtime_ns)
        for stale in old[:-KEEP]:
            stale.unlink(missing_ok=True)
    except (OSError, HackError):
        pass  # a read-only or full cache folder: the render goes on without it


class _Tee(io.TextIOBase):
    def __init__(self, *streams):
        self.streams = streams

    def write(self, text):
        for s in self.streams:
            s.write(text)
        return len(text)

    def flush(self):
        for s in self.streams:
            s.flush()
