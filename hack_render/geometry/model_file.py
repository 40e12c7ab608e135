"""The HACK model file: one ``.npz`` with a format version and named arrays, validated on load.

Layout (N vertices, F triangles, T texture coordinates, S shape components, E expression
shapes, K = 8 joints; "opt" groups are all-or-none):

====================== ===================== ==========================================
key                    shape, dtype          meaning
====================== ===================== ==========================================
format_version         (), int               :data:`FORMAT_VERSION`
meta_json              (), str               provenance per component, units, licence
template_vertices      (N, 3) f32            mean rest template T_bar, metres, Y up, +Z face
faces / uv_faces       (F, 3) i32            triangles; their texture-coordinate indices
uvs                    (T, 2) f32            texture coordinates (UDIM-like tiles in u)
face_material          (F,) i16              index into material_names
material_names         (n,) str              ICT material names
vertex_uv              (N, 2) f32            one UV per vertex (first use), for UV lookups
vertex_group / group_names (N,) i16 / str     ICT geometry groups
vertex_region / region_names (N,) i16 / str   skin regions (face, scalp, neck, chest, ...)
landmark_indices       (68,) i32             Multi-PIE 68 landmark vertices
shape_components       (S, N, 3) f32 q       orthonormal PCA basis (as vectors in R^3N)
shape_std              (S,) f32              std of each component, metres; beta ~ N(0, I)
expression_basis       (E, N, 3) f32 q       generic expression deltas, metres
expression_names       (E,) str
au_names / au_matrix   (A,) str / (A, E) f32 FACS action unit -> expression weights
joint_names            (K,) str
joint_parents          (K,) i32              -1 = root (thorax)
joint_regressor        (K, N) f32            J = regressor @ (T_bar + B_S), rows sum to 1
skinning_weights       (N, K+1) f32          column 0 = root, then joints; rows sum to 1
rotation_limits_deg    (K, 3, 2) f32         Euler (x, y, z) (min, max) per joint
opt pose_basis         (9K, N, 3) f32 q      generic pose blendshapes P (SMPL-style)
opt pose_gate_deg      (), f32               format 3: each joint's pose feature gated by its
                                             angle (:func:`~hack_render.geometry.lbs.pose_gate`)
opt pose_gate_chain    (), f32               format 4: the gate also opened by the chain's net
                                             rotation (needs ``pose_gate_deg``)
opt expr_pca_*         see below             personalised expressions E_beta = M_E(beta)
opt pose_pca_*         see below             personalised pose blendshapes P_beta = M_P(beta)
opt larynx_*           see below             larynx basis L (Eq. 4)
opt flex_*             see below             format 5: the flexion block F(beta, theta)
====================== ===================== ==========================================

Personalised group ``X`` in {expr, pose} (D = E or 9K deltas): ``X_pca_vertices`` (M,) i32,
``X_pca_mean`` (D, M, 3), ``X_pca_components`` (C, D, M, 3) q, and an MLP of three linear
layers ``X_mlp_w0`` (H, S_in), ``X_mlp_b0`` (H,), ``X_mlp_w1`` (H, H), ``X_mlp_b1``,
``X_mlp_w2`` (C, H), ``X_mlp_b2`` (C,) with ReLU between them. The personal basis is the
generic one plus, on the M vertices, ``mean + sum_c w_c(beta) components_c``.

Larynx: ``larynx_maps`` (L, 3, H, W) metres, ``larynx_uv_bounds`` (4,), ``larynx_vertices``
(M,) i32, ``larynx_coef_matrix`` (L, S'), ``larynx_coef_offset`` (L,),
``larynx_v_per_metre`` (). See :mod:`hack_render.geometry.larynx`. Format 2 adds the
optional ``larynx_vertex_uv`` (M, 2): the larynx vertices' coordinates in the maps' own
chart (e.g. template x, y in metres, so a v shift is a vertical slide of the same size on
every vertex); without it the atlas ``vertex_uv`` is used. Format 3 adds the optional
``pose_gate_deg`` (): the angle c of the pose correctives' gate, degrees (each joint's
``R - I`` block scaled by about angle^4 / (angle^4 + c^4)); without it (files of format 1
and 2, which still load) the features are plain ``R - I``. Format 4 adds the optional
``pose_gate_chain`` () = lambda: each joint's gate also counts lambda times the squared
net rotation of the whole chain (:func:`~hack_render.geometry.lbs.pose_gate`), so a nod
spread over the joints opens every joint's gate; without it (files of format 1 to 3) 0.
Format 5 adds the optional flexion block (:mod:`hack_render.geometry.flex_block`):
``flex_vertices`` (Mf,) i32, ``flex_basis`` (Hf, Tf, Mf, 3) f32 q (per hat: the offsets
for every identity, then one per shape weight, Tf = 1 + S_f), ``flex_knots_deg`` (Hf,)
(sorted, none at 0), ``flex_width_deg`` () and ``flex_purity_deg`` () (both > 0) and
``flex_coherence`` () (the power of the joints' flexion coherence, 0 to 16): rest-space
offsets weighted by hats over the chain's net flexion angle; without it (files of format
1 to 4, which still load) none.

"q" arrays may be stored quantised as ``key__q`` (int16) with ``key__scale`` (f32, one per
leading index, value = q * scale); the loader restores float32 transparently.

Unpacking the file (inflating ~70 MB, restoring the quantised arrays, validating) takes
~0.55 CPU s, a third of a new pose's `hack-render render`. So the first load of a file
keeps its validated arrays, uncompressed, in ``$XDG_CACHE_HOME/hack-render/models/<key>/``
(one ``.npy`` each and ``index.json``; the key is the file's resolved path, size and
modification time), and later loads map them copy-on-write (``np.load(mmap_mode="c")``,
no pickle): ~0.01 s. The newest :data:`CACHE_KEEP` models are kept; a cache that cannot
be read is ignored and rewritten, one that cannot be written warns
(:class:`CacheWarning`); ``HACK_RENDER_NO_CACHE=1`` turns it off.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
import zipfile
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from hack_render.errors import HackError
from hack_render.io.array_folder import cache_base, read_array_folder, write_array_folder
from hack_render.io.npz import write_npz

FORMAT_VERSION = 5
#: the built-in default model's file name in the package data (``hack_render/data``)
DEFAULT_MODEL_NAME = "hack_default.npz"
SUPPORTED_VERSIONS = (1, 2, 3, 4, 5)
QUANTISABLE = ("shape_components", "expression_basis", "pose_basis",
               "expr_pca_components", "pose_pca_components", "flex_basis")
class CacheWarning(UserWarning):
    """The unpacked model file could not be cached (the load itself went through)."""


#: Unpacked model files kept in the cache (~0.15 GB each for the default model).
CACHE_KEEP = 3
_CACHE_FORMAT = 1
_CACHE_OFF = "HACK_RENDER_NO_CACHE"
_FIX = "Rebuild the file with `hack-render learn base-model`, or pass a valid HACK model file."

REQUIRED: dict[str, tuple[str, str]] = {
    # key: (shape spec, dtype kind) -- symbols resolved against the template's sizes
    "template_vertices": ("N,3", "f"),
    "faces": ("F,3", "i"),
    "uvs": ("T,2", "f"),
    "uv_faces": ("F,3", "i"),
    "face_material": ("F", "i"),
    "material_names": ("*", "U"),
    "vertex_uv": ("N,2", "f"),
    "vertex_group": ("N", "i"),
    "group_names": ("*", "U"),
    "vertex_region": ("N", "i"),
    "region_names": ("*", "U"),
    "landmark_indices": ("68", "i"),
    "shape_components": ("S,N,3", "f"),
    "shape_std": ("S", "f"),
    "expression_basis": ("E,N,3", "f"),
    "expression_names": ("E", "U"),
    "au_names": ("A", "U"),
    "au_matrix": ("A,E", "f"),
    "joint_names": ("K", "U"),
    "joint_parents": ("K", "i"),
    "joint_regressor": ("K,N", "f"),
    "skinning_weights": ("N,K1", "f"),
    "rotation_limits_deg": ("K,3,2", "f"),
}
OPTIONAL_GROUPS: dict[str, dict[str, tuple[str, str]]] = {
    "pose": {"pose_basis": ("P,N,3", "f")},
    "expr_personal": {
        "expr_pca_vertices": ("Me", "i"), "expr_pca_mean": ("E,Me,3", "f"),
        "expr_pca_components": ("Ce,E,Me,3", "f"),
        "expr_mlp_w0": ("He,Ie", "f"), "expr_mlp_b0": ("He", "f"),
        "expr_mlp_w1": ("He,He", "f"), "expr_mlp_b1": ("He", "f"),
        "expr_mlp_w2": ("Ce,He", "f"), "expr_mlp_b2": ("Ce", "f"),
    },
    "pose_personal": {
        "pose_pca_vertices": ("Mp", "i"), "pose_pca_mean": ("P,Mp,3", "f"),
        "pose_pca_components": ("Cp,P,Mp,3", "f"),
        "pose_mlp_w0": ("Hp,Ip", "f"), "pose_mlp_b0": ("Hp", "f"),
        "pose_mlp_w1": ("Hp,Hp", "f"), "pose_mlp_b1": ("Hp", "f"),
        "pose_mlp_w2": ("Cp,Hp", "f"), "pose_mlp_b2": ("Cp", "f"),
    },
    "larynx": {
        "larynx_maps": ("L,3,Hl,Wl", "f"), "larynx_uv_bounds": ("4", "f"),
        "larynx_vertices": ("Ml", "i"), "larynx_coef_matrix": ("L,Sl", "f"),
        "larynx_coef_offset": ("L", "f"), "larynx_v_per_metre": ("", "f"),
    },
    "larynx_chart": {"larynx_vertex_uv": ("Ml,2", "f")},
    "pose_gate": {"pose_gate_deg": ("", "f")},
    "pose_gate_chain": {"pose_gate_chain": ("", "f")},
    "flex": {"flex_vertices": ("Mf", "i"), "flex_basis": ("Hf,Tf,Mf,3", "f"),
             "flex_knots_deg": ("Hf", "f"), "flex_width_deg": ("", "f"),
             "flex_purity_deg": ("", "f"), "flex_coherence": ("", "f")},
}


def _resolve(spec: str, arr: np.ndarray, sizes: dict[str, int], key: str, path: str) -> None:
    dims = [d for d in spec.split(",") if d] if spec else []
    if spec == "*":
        if arr.ndim != 1:
            raise HackError(f"{path}: key '{key}' expected a 1-D array, found shape {arr.shape}. {_FIX}")
        return
    if arr.ndim != len(dims):
        raise HackError(f"{path}: key '{key}' expected shape ({spec}), found {arr.shape}. {_FIX}")
    for d, n in zip(dims, arr.shape):
        if d.isdigit():
            want = int(d)
        elif d == "K1":
            want = sizes.setdefault("K", n - 1) + 1
        else:
            want = sizes.setdefault(d, n)
        if n != want:
            raise HackError(f"{path}: key '{key}' expected shape ({spec}) with {d}={want} "
                            f"(from earlier keys), found {arr.shape}. {_FIX}")


def quantise(arr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """int16 quantisation with one scale per leading index; returns (q, scale)."""
    flat = arr.reshape(arr.shape[0], -1).astype(np.float64)
    scale = np.abs(flat).max(axis=1) / 32767.0
    scale[scale == 0] = 1.0
    q = np.round(flat / scale[:, None]).astype(np.int16).reshape(arr.shape)
    return q, scale.astype(np.float32)


def dequantise(q: np.ndarray, scale: np.ndarray) -> np.ndarray:
    return (q.astype(np.float32).reshape(q.shape[0], -1) * scale[:, None]).reshape(q.shape)


def save_model_file(path: str | Path, arrays: dict[str, Any], meta: dict[str, Any],
                    quantise_keys: tuple[str, ...] = QUANTISABLE) -> dict[str, float]:
    """Validate and write a model file atomically.

    Returns:
        the maximum absolute quantisation error (metres) per quantised key.
    """
    path = Path(path)
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    validate_arrays(arrays, str(path))
    out: dict[str, np.ndarray] = {"format_version": np.asarray(FORMAT_VERSION),
                                  "meta_json": np.asarray(json.dumps(meta, indent=1))}
    errors: dict[str, float] = {}
    for k, v in arrays.items():
        if k in quantise_keys and v.size:
            q, s = quantise(v)
            out[f"{k}__q"], out[f"{k}__scale"] = q, s
            errors[k] = float(np.abs(dequantise(q, s) - v).max())
        else:
            out[k] = v
    write_npz(path, out, compressed=True)
    return errors


def load_model_file(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read and validate a model file; returns (arrays, meta). Raises HackError on any problem.

    The arrays come from the unpacked cache where it holds this file (see the module
    docstring): writable copy-on-write maps of the same values."""
    path = Path(path)
    if not path.is_file():
        raise HackError(f"{path}: model file not found. Pass an existing .npz, or omit it to use "
                        "the built-in default model.")
    cache = _cache_entry(path)
    hit = read_array_folder(cache, mmap=True) if cache is not None else None
    if hit is not None:
        return hit
    arrays, meta = _unpack(path)
    if cache is not None:
        _write_cache(cache, arrays, meta)
    return arrays, meta


def file_header(path: str | Path) -> tuple[int, dict[str, Any]]:
    """(format version, metadata) of a model file, read without its arrays (for
    ``hack-render --version`` and ``model info``)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if "format_version" not in z.files:
                raise HackError(f"{path}: missing key 'format_version'; this is not a HACK "
                                f"model file. {_FIX}")
            version = int(z["format_version"])
            meta = json.loads(str(z["meta_json"])) if "meta_json" in z.files else {}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise HackError(f"{path}: not a readable .npz model file ({exc}); it may be truncated "
                        f"or corrupt. {_FIX}") from exc
    return version, meta


def _cache_entry(path: Path) -> Path | None:
    """The cache folder of ``path`` (None when the cache is off)."""
    if os.environ.get(_CACHE_OFF, "") not in ("", "0"):
        return None
    st = path.stat()
    key = json.dumps([_CACHE_FORMAT, FORMAT_VERSION, str(path.resolve()), st.st_size,
                      st.st_mtime_ns])
    return cache_base() / "models" / hashlib.sha256(key.encode()).hexdigest()[:32]


def _write_cache(folder: Path, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
    """Write the unpacked arrays to ``folder`` and keep the newest :data:`CACHE_KEEP`
    entries. Failures only cost speed."""
    try:
        write_array_folder(folder, arrays, meta, CACHE_KEEP)
    except OSError as err:  # a full disk, a read-only cache: loads stay slower, no more
        warnings.warn(f"could not cache the unpacked model file in {folder.parent} ({err}); "
                      "every load unpacks the file again (~0.5 s). Free space there, set "
                      "XDG_CACHE_HOME, or HACK_RENDER_NO_CACHE=1 to skip the cache.",
                      CacheWarning, stacklevel=3)


def _unpack(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    try:
        with np.load(path, allow_pickle=False) as z:
            raw = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise HackError(f"{path}: not a readable .npz model file ({exc}); it may be truncated "
                        f"or corrupt. {_FIX}") from exc
    if "format_version" not in raw:
        raise HackError(f"{path}: missing key 'format_version'; this is not a HACK model file. {_FIX}")
    version = int(raw.pop("format_version"))
    if version not in SUPPORTED_VERSIONS:
        raise HackError(f"{path}: format_version {version} is not supported (expected one of "
                        f"{SUPPORTED_VERSIONS}). {_FIX}")
    meta = json.loads(str(raw.pop("meta_json"))) if "meta_json" in raw else {}
    arrays: dict[str, np.ndarray] = {}
    for k, v in raw.items():
        if k.endswith("__q"):
            base = k[:-3]
            if f"{base}__scale" not in raw:
                raise HackError(f"{path}: key '{base}__q' has no '{base}__scale'. {_FIX}")
            arrays[base] = dequantise(v, raw[f"{base}__scale"])
        elif not k.endswith("__scale"):
            arrays[k] = v
    validate_arrays(arrays, str(path))
    return arrays, meta


def validate_arrays(arrays: dict[str, np.ndarray], path: str = "model") -> dict[str, int]:
    """Check keys, shapes, dtypes and finiteness; returns the resolved sizes (N, F, S, ...)."""
    sizes: dict[str, int] = {}
    for key, (spec, kind) in REQUIRED.items():
        if key not in arrays:
            raise HackError(f"{path}: missing required key '{key}' (shape ({spec})). {_FIX}")
        _check(key, arrays[key], spec, kind, sizes, path)
    for group, keys in OPTIONAL_GROUPS.items():
        present = [k for k in keys if k in arrays]
        if present and len(present) != len(keys):
            missing = sorted(set(keys) - set(present))
            raise HackError(f"{path}: optional group '{group}' is incomplete: has {present}, "
                            f"missing {missing}. {_FIX}")
        for key in present:
            _check(key, arrays[key], *keys[key], sizes, path)
    known = set(REQUIRED) | {k for g in OPTIONAL_GROUPS.values() for k in g}
    unknown = sorted(set(arrays) - known)
    if unknown:
        raise HackError(f"{path}: unknown keys {unknown}. {_FIX}")
    if "larynx_vertex_uv" in arrays and "larynx_maps" not in arrays:
        raise HackError(f"{path}: key 'larynx_vertex_uv' needs the 'larynx' group (larynx_maps, "
                        f"...). {_FIX}")
    if "pose_gate_deg" in arrays and not 0.0 < float(arrays["pose_gate_deg"]) <= 90.0:
        raise HackError(f"{path}: key 'pose_gate_deg' is {float(arrays['pose_gate_deg'])}, "
                        f"expected an angle in (0, 90] degrees. {_FIX}")
    if "pose_gate_chain" in arrays:
        if "pose_gate_deg" not in arrays:
            raise HackError(f"{path}: key 'pose_gate_chain' needs 'pose_gate_deg' (the gate "
                            f"it opens). {_FIX}")
        if not 0.0 <= float(arrays["pose_gate_chain"]) <= 100.0:
            raise HackError(f"{path}: key 'pose_gate_chain' is "
                            f"{float(arrays['pose_gate_chain'])}, expected a weight in [0, 100]. "
                            f"{_FIX}")
    if "flex_basis" in arrays:
        _check_flex(arrays, sizes, path)
    n = sizes["N"]
    for key in ("faces", "landmark_indices", *(("flex_vertices",) if "flex_basis" in arrays
                                               else ())):
        if arrays[key].min() < 0 or arrays[key].max() >= n:
            raise HackError(f"{path}: key '{key}' indexes outside 0..{n - 1}. {_FIX}")
    if arrays["uv_faces"].max() >= sizes["T"]:
        raise HackError(f"{path}: key 'uv_faces' indexes outside 0..{sizes['T'] - 1}. {_FIX}")
    w = arrays["skinning_weights"]
    if w.min() < -1e-6 or np.abs(w.sum(1) - 1).max() > 1e-4:
        raise HackError(f"{path}: key 'skinning_weights' must be non-negative with rows summing "
                        f"to 1; found min {w.min():.3g}, worst row sum error "
                        f"{np.abs(w.sum(1) - 1).max():.3g}. {_FIX}")
    if np.abs(arrays["joint_regressor"].sum(1) - 1).max() > 1e-4:
        raise HackError(f"{path}: key 'joint_regressor' rows must sum to 1 (translation "
                        f"equivariance). {_FIX}")
    return sizes


def _check_flex(arrays: dict[str, np.ndarray], sizes: dict[str, int], path: str) -> None:
    """The flexion block's (format 5) knots, widths and shape terms."""
    knots = np.asarray(arrays["flex_knots_deg"], np.float64)
    if np.any(np.diff(knots) <= 0) or np.any(knots == 0) or np.any(np.abs(knots) > 180):
        raise HackError(f"{path}: key 'flex_knots_deg' must be increasing angles in "
                        f"[-180, 180] degrees without 0 (the block vanishes at rest); found "
                        f"{knots.tolist()}. {_FIX}")
    for key in ("flex_width_deg", "flex_purity_deg"):
        if not 0.0 < float(arrays[key]) <= 180.0:
            raise HackError(f"{path}: key '{key}' is {float(arrays[key])}, expected an angle "
                            f"in (0, 180] degrees. {_FIX}")
    if not 0.0 <= float(arrays["flex_coherence"]) <= 16.0:
        raise HackError(f"{path}: key 'flex_coherence' is {float(arrays['flex_coherence'])}, "
                        f"expected a power in [0, 16]. {_FIX}")
    if not 1 <= sizes["Tf"] <= sizes["S"] + 1:
        raise HackError(f"{path}: key 'flex_basis' has {sizes['Tf']} terms per hat, expected "
                        f"1 to 1 + {sizes['S']} (one, then one per shape weight). {_FIX}")


def _check(key, arr, spec, kind, sizes, path):
    if kind == "f" and arr.dtype.kind != "f":
        raise HackError(f"{path}: key '{key}' expected a float array, found dtype {arr.dtype}. {_FIX}")
    if kind == "i" and arr.dtype.kind not in "iu":
        raise HackError(f"{path}: key '{key}' expected an integer array, found dtype {arr.dtype}. {_FIX}")
    if kind == "U" and arr.dtype.kind != "U":
        raise HackError(f"{path}: key '{key}' expected an array of strings, found dtype {arr.dtype}. {_FIX}")
    _resolve(spec, arr, sizes, key, path)
    if kind == "f" and not np.isfinite(arr).all():
        bad = int((~np.isfinite(arr)).sum())
        raise HackError(f"{path}: key '{key}' has {bad} non-finite values (NaN or inf). {_FIX}")


def without_correctives(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays less every pose corrective (the per-joint and personalised ones, their
    gate, the flexion block): the model's skin under plain LBS."""
    return {k: v for k, v in arrays.items() if not k.startswith(("pose_", "flex_"))}


def default_model_path() -> Path:
    """Path of the built-in default model shipped as package data."""
    path = Path(str(resources.files("hack_render") / "data" / DEFAULT_MODEL_NAME))
    if not path.is_file():
        raise HackError(f"the built-in default model {path} is missing: reinstall "
                        f"hack-render, or rebuild it from ICT-FaceKit (public, MIT licence; "
                        f"github.com/ICT-VGL/ICT-FaceKit) with `hack-render model build-v2 "
                        f"--ict ICT_FACEKIT_DIR -o {path}`.")
    return path
