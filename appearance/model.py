"""The appearance model A(alpha): a PCA over skin UV maps, evaluated in torch.

Contract with the renderer (``hack_render/render/materials.py`` consumes it):

- Maps are atlases covering u in [0, 2], v in [0, 1], shape (H, 2H): the left half is
  tile 0 (``M_Face``), the right half tile 1 (``M_BackHead``); image row 0 is v = 1.
- :meth:`AppearanceModel.maps` returns :class:`AppearanceMaps` with torch tensors
  ``diffuse`` (B, H, 2H, 3) linear Rec.709 albedo in [0, 1]; ``specular`` (B, H, 2H, 1)
  intensity in [0, 1], the scale of a Schlick lobe with F0 = 0.028 (skin, n = 1.4), so
  1 means full skin Fresnel and 0 no specular; ``roughness`` (B, H, 2H, 1) *perceptual*
  roughness r (GGX alpha = r^2); ``normal`` (B, H, 2H, 3) unit tangent-space normals,
  OpenGL convention (+X along +u, +Y along +v), n_z > 0, raw values in [-1, 1];
  ``mask`` (H, 2H) bool of valid texels. Texels outside the islands hold the value of
  the nearest valid texel of the same tile (dilation), so bilinear lookups at island
  borders never blend in invalid texels and nothing bleeds between the tiles.
- alpha ~ N(0, I): component k is scaled by its standard deviation. alpha of shape
  (B, k) uses the first k components (the number of components is a call-time choice).
- Close-ups: :func:`appearance.detail.compose_detail` adds the high-resolution procedural
  pore layer to ``normal`` at a requested resolution.

Internally the model stores, for the valid texels only (N of them), a mean and a basis
over C = 7 channels per texel: diffuse RGB, specular, roughness and the two normal
*slopes* (p, q) = (n_x / n_z, n_y / n_z) (a linear space, unlike unit vectors; the
normal is (p, q, 1) normalised). Diffuse, specular, roughness and normals share one
coefficient vector (a joint PCA, as AlbedoMM does for diffuse and specular), with each
block weighted to equal total variance when the PCA was built.

The model file is one ``.npz`` (format ``hack-appearance-model``, version 1), validated
on load: keys, shapes, dtypes and finite values; the basis may be stored as float32,
float16 or int8 with a per (component, channel) scale.

Unpacking the shipped file (inflating it, restoring the int8 basis, validating) costs
~0.4 CPU s, a tenth of a dataset's start-up, so :meth:`AppearanceModel.load` keeps the
validated arrays of a file, uncompressed, in ``$XDG_CACHE_HOME/hack-render/appearance/``
(``appearance.cache.cached_arrays``: keyed by the file's path, size and modification
time and this module's source) and later loads map them copy-on-write (no pickle);
``HACK_RENDER_NO_CACHE=1`` turns the cache off. The arrays are the same bits either way.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from appearance.cache import cached_arrays, file_key, source_key
from appearance.uv import fill_index
from hack_render.errors import HackError
from hack_render.io.npz import write_npz

FORMAT = "hack-appearance-model"
VERSION = 1
CHANNELS = ("diffuse_r", "diffuse_g", "diffuse_b", "specular", "roughness", "slope_u", "slope_v")
N_CHANNELS = len(CHANNELS)
BLOCKS = {"diffuse": slice(0, 3), "specular": slice(3, 4), "roughness": slice(4, 5),
          "normal": slice(5, 7)}
DEFAULT_MODEL = Path(__file__).resolve().parent / "data" / "default_appearance.npz"
ROUGHNESS_RANGE = (0.02, 1.0)


@dataclass(frozen=True)
class AppearanceMaps:
    """Output of :meth:`AppearanceModel.maps` (see the module docstring for units).

    diffuse (B, H, 2H, 3); specular (B, H, 2H, 1); roughness (B, H, 2H, 1);
    normal (B, H, 2H, 3); mask (H, 2H) bool.
    """

    diffuse: torch.Tensor
    specular: torch.Tensor
    roughness: torch.Tensor
    normal: torch.Tensor
    mask: torch.Tensor


def slopes_to_normals(slopes: torch.Tensor) -> torch.Tensor:
    """(..., 2) slopes (p, q) to (..., 3) unit normals (p, q, 1) / |(p, q, 1)|."""
    one = torch.ones_like(slopes[..., :1])
    n = torch.cat([slopes, one], -1)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True)


def normals_to_slopes(normals: np.ndarray, min_z: float = 0.1) -> np.ndarray:
    """(..., 3) normals to (..., 2) slopes (n_x / n_z, n_y / n_z); n_z clamped to ``min_z``."""
    n = np.asarray(normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    z = np.maximum(n[..., 2:3], min_z)
    return (n[..., :2] / z).astype(np.float32)


_REQUIRED = {"format": None, "version": None, "height": None, "mask": np.bool_,
             "mean": np.float32, "basis": None, "stddev": np.float32,
             "explained_variance_ratio": np.float32, "metadata": None}


class AppearanceModel:
    """A(alpha) -> physically based skin maps. Stateless per call; batched; differentiable.

    Buffers (torch, on the model's device/dtype): ``mean`` (N * 7,), ``basis`` (K, N * 7)
    (already multiplied by the per-component standard deviation, so alpha ~ N(0, I)),
    ``gather`` (H * 2H,) index of the valid texel each atlas texel reads.
    """

    def __init__(self, height: int, mask: np.ndarray, mean: np.ndarray, basis: np.ndarray,
                 stddev: np.ndarray, explained_variance_ratio: np.ndarray,
                 metadata: dict | None = None, report: dict | None = None):
        self.height = int(height)
        self.mask_np = np.asarray(mask, bool)
        self.metadata = dict(metadata or {})
        self.report = dict(report or {})
        self.stddev_np = np.asarray(stddev, np.float32)
        self.explained_variance_ratio = np.asarray(explained_variance_ratio, np.float32)
        valid = np.flatnonzero(self.mask_np)
        compact = np.full(self.mask_np.size, -1, np.int64)
        compact[valid] = np.arange(len(valid))
        gather = compact[fill_index(self.mask_np)]
        self.n_valid = len(valid)
        self.mean = torch.from_numpy(np.asarray(mean, np.float32))
        self.basis = torch.from_numpy(np.asarray(basis, np.float32)
                                      * self.stddev_np[:, None])
        self.gather = torch.from_numpy(gather)
        self.mask = torch.from_numpy(self.mask_np)

    # -- properties -------------------------------------------------------------------
    @property
    def n_components(self) -> int:
        return int(self.basis.shape[0])

    @property
    def device(self) -> torch.device:
        return self.basis.device

    @property
    def dtype(self) -> torch.dtype:
        return self.basis.dtype

    def to(self, device=None, dtype=None) -> AppearanceModel:
        """Move the buffers (in place) to ``device`` / ``dtype``; returns self."""
        self.mean = self.mean.to(device=device, dtype=dtype)
        self.basis = self.basis.to(device=device, dtype=dtype)
        self.gather = self.gather.to(device=device)
        self.mask = self.mask.to(device=device)
        return self

    # -- evaluation -------------------------------------------------------------------
    def compact(self, alpha: torch.Tensor) -> torch.Tensor:
        """(B, N, 7) valid-texel channels for alpha (B, k): mean + alpha @ basis[:k]."""
        alpha = self._check_alpha(alpha)
        k = alpha.shape[1]
        basis = self.basis[:k]
        mean = self.mean
        if alpha.dtype != basis.dtype or alpha.device != basis.device:
            basis, mean = basis.to(alpha), mean.to(alpha)
        # (B, k) x (k, N*7): one matrix product reads the basis once.
        flat = torch.addmm(mean.unsqueeze(0), alpha, basis) if k else mean.expand(len(alpha), -1)
        return flat.view(len(alpha), self.n_valid, N_CHANNELS)

    def maps(self, alpha: torch.Tensor) -> AppearanceMaps:
        """Skin maps for appearance parameters ``alpha``.

        Args:
            alpha: (B, k) with k <= :attr:`n_components` (or (k,) for B = 1), any float
                dtype; gradients flow to it. alpha = 0 gives the mean appearance.
        Returns:
            :class:`AppearanceMaps` (see the module docstring), on alpha's device and dtype.
        """
        c = self.compact(alpha)
        b, h = c.shape[0], self.height
        # Work on the N valid texels (fewer than H * 2H), then one gather dilates all maps:
        # one clamp over the 5 bounded channels, normals from slopes, one concatenation.
        lo = c.new_tensor([0.0, 0.0, 0.0, 0.0, ROUGHNESS_RANGE[0]])
        hi = c.new_tensor([1.0, 1.0, 1.0, 1.0, ROUGHNESS_RANGE[1]])
        bounded = torch.clamp(c[..., :5], min=lo, max=hi)
        slopes = c[..., BLOCKS["normal"]]
        inv = torch.rsqrt(1.0 + (slopes * slopes).sum(-1, keepdim=True))
        packed = torch.cat([bounded, slopes * inv, inv], -1)  # (B, N, 8)
        # a gather along dim 0 of the (B N, 8) rows: index_select on dim 1 of (B, N, 8)
        # takes a slow path (backward ~2.7x slower on the CPU)
        idx = self.gather.to(c.device)
        if b > 1:
            idx = (idx[None] + self.n_valid * torch.arange(b, device=c.device)[:, None]).reshape(-1)
        img = packed.reshape(b * self.n_valid, 8).index_select(0, idx).view(b, h, 2 * h, 8)
        diffuse, specular, rough, normal = img[..., :3], img[..., 3:4], img[..., 4:5], img[..., 5:]
        return AppearanceMaps(diffuse, specular, rough, normal, self.mask.to(c.device))

    def downsampled(self, height: int, n_components: int | None = None) -> AppearanceModel:
        """This model at a coarser atlas, ``height`` = :attr:`height` / 2^k: a mip level.

        The mean and the first ``n_components`` basis vectors (default: all) are box-
        filtered over f x f texel blocks (f = height ratio) of the dilated atlas, in the
        linear channels (diffuse, specular, roughness, normal slopes), so the coarse
        model's maps for any alpha equal the box-filtered fine maps of the linear
        channels; the clamp and the slope-to-normal step then act per coarse texel. A
        coarse texel is valid when any of its fine texels is. Blocks never straddle the
        two tiles (the tile width, H, is a multiple of f). For renders whose pixels
        cover several texels (the fitter's coarse photometric levels).
        """
        h = self.height
        f = h // int(height) if height > 0 else 0
        if height <= 0 or h % height or f & (f - 1):
            raise HackError(f"downsampled: expected a height of {h} / 2^k, found {height}.")
        k = self.n_components if n_components is None else int(n_components)
        if not 0 <= k <= self.n_components:
            raise HackError(f"n_components: expected 0..{self.n_components}, found {k}.")
        if f == 1 and k == self.n_components:
            return self
        mask = self.mask_np.reshape(height, f, 2 * height, f).any(axis=(1, 3))
        valid = torch.from_numpy(np.flatnonzero(mask))

        def pool(flat: torch.Tensor) -> np.ndarray:  # (M, N*7) -> (M, N'*7)
            m = flat.shape[0]
            img = flat.view(m, self.n_valid, N_CHANNELS)[:, self.gather]
            img = img.view(m, h, 2 * h, N_CHANNELS).permute(0, 3, 1, 2)
            img = torch.nn.functional.avg_pool2d(img, f) if f > 1 else img
            img = img.permute(0, 2, 3, 1).reshape(m, -1, N_CHANNELS)[:, valid]
            return img.reshape(m, -1).numpy()

        with torch.no_grad():
            mean = pool(self.mean.float()[None])[0]
            basis = pool(self.basis[:k].float())  # already scaled by stddev
        out = AppearanceModel(height, mask, mean, basis, np.ones(k, np.float32),
                              self.explained_variance_ratio[:k],
                              dict(self.metadata, downsampled_from=h), self.report)
        out.stddev_np = self.stddev_np[:k].copy()
        return out.to(self.device, self.dtype)

    def sample_alpha(self, n: int, n_components: int | None = None, seed: int | None = None
                     ) -> torch.Tensor:
        """(n, k) alpha ~ N(0, I) from a seeded generator (k defaults to all components)."""
        k = self.n_components if n_components is None else int(n_components)
        if not 0 <= k <= self.n_components:
            raise HackError(f"n_components: expected 0..{self.n_components}, found {k}.")
        g = torch.Generator().manual_seed(0 if seed is None else int(seed))
        return torch.randn(n, k, generator=g, dtype=torch.float64).to(self.dtype)

    def project(self, compact: torch.Tensor, n_components: int | None = None) -> torch.Tensor:
        """Least-squares alpha (B, k) of valid-texel channels (B, N, 7) in the first k components."""
        k = self.n_components if n_components is None else int(n_components)
        a = self.basis[:k].to(compact)
        r = (compact.reshape(len(compact), -1) - self.mean.to(compact))
        return torch.linalg.solve(a @ a.T, a @ r.T).T

    def _check_alpha(self, alpha) -> torch.Tensor:
        if not isinstance(alpha, torch.Tensor):
            raise HackError(f"alpha: expected a torch.Tensor of shape (B, k), found "
                            f"{type(alpha).__name__}. Wrap it with torch.as_tensor.")
        if alpha.ndim == 1:
            alpha = alpha.unsqueeze(0)
        if alpha.ndim != 2 or alpha.shape[1] > self.n_components:
            raise HackError(f"alpha: expected shape (B, k) with k <= {self.n_components}, "
                            f"found {tuple(alpha.shape)}. Use fewer components.")
        if not alpha.is_floating_point():
            raise HackError(f"alpha: expected a floating dtype, found {alpha.dtype}.")
        return alpha

    # -- file IO ----------------------------------------------------------------------
    @staticmethod
    def load(path: str | os.PathLike | None = None) -> AppearanceModel:
        """Load and validate a model file (default: the shipped procedural model); the
        validated arrays come from the cache when it holds them (``appearance.cache``)."""
        path = Path(path or DEFAULT_MODEL)
        if not path.is_file():
            return AppearanceModel(**load_model_arrays(path))  # raises, naming the fix
        names = ("height", "mask", "mean", "basis", "stddev", "explained_variance_ratio")

        def unpack() -> tuple[dict[str, np.ndarray], dict]:
            a = load_model_arrays(path)
            return ({k: np.asarray(a[k]) for k in names},
                    {"metadata": a["metadata"], "report": a["report"]})

        arrays, extra = cached_arrays("model", [file_key(path), source_key(__file__)],
                                      unpack, mmap=True)
        return AppearanceModel(**dict(arrays, height=int(arrays["height"])), **extra)


def _fail(path, what, expected, found, fix="Rebuild it with `hack-render learn appearance`."):
    raise HackError(f"{path}: {what}: expected {expected}, found {found}. {fix}")


def load_model_arrays(path) -> dict:
    """Read and validate a model ``.npz``; returns the constructor arguments."""
    path = Path(path)
    if not path.is_file():
        _fail(path, "appearance model", "an existing .npz file", "no file",
              "Pass a model built by `hack-render learn appearance`.")
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as exc:
        _fail(path, "appearance model", "a readable .npz file", f"an unreadable file ({exc})")
    missing = [k for k in _REQUIRED if k not in z.files]
    if missing:
        _fail(path, "keys", sorted(_REQUIRED), f"missing {missing}")
    if str(z["format"]) != FORMAT:
        _fail(path, "format", FORMAT, str(z["format"]))
    if int(z["version"]) != VERSION:
        _fail(path, "version", VERSION, int(z["version"]))
    h, mask = int(z["height"]), z["mask"]
    if mask.dtype != np.bool_ or mask.shape != (h, 2 * h):
        _fail(path, "mask", f"bool ({h}, {2 * h})", f"{mask.dtype} {mask.shape}")
    d = int(mask.sum()) * N_CHANNELS
    mean, stddev, evr = z["mean"], z["stddev"], z["explained_variance_ratio"]
    basis = z["basis"]
    k = len(stddev)
    if mean.shape != (d,):
        _fail(path, "mean", f"shape ({d},)", mean.shape)
    if basis.shape != (k, d):
        _fail(path, "basis", f"shape ({k}, {d})", basis.shape)
    if basis.dtype == np.int8:
        if "basis_scale" not in z.files or z["basis_scale"].shape != (k, N_CHANNELS):
            _fail(path, "basis_scale", f"shape ({k}, {N_CHANNELS}) for an int8 basis",
                  z["basis_scale"].shape if "basis_scale" in z.files else "none")
        basis = (basis.reshape(k, -1, N_CHANNELS).astype(np.float32)
                 * z["basis_scale"][:, None, :].astype(np.float32)).reshape(k, d)
    elif basis.dtype not in (np.float16, np.float32):
        _fail(path, "basis dtype", "float32, float16 or int8", basis.dtype)
    basis = basis.astype(np.float32)
    for name, arr in (("mean", mean), ("basis", basis), ("stddev", stddev),
                      ("explained_variance_ratio", evr)):
        if not np.all(np.isfinite(arr)):
            _fail(path, name, "finite values", "NaN/Inf")
    if evr.shape != (k,) or np.any(np.diff(stddev) > 1e-6 * max(float(stddev.max(initial=0)), 1)):
        _fail(path, "stddev / explained_variance_ratio", f"({k},) non-increasing",
              f"{stddev.shape} / {evr.shape}")
    meta = json.loads(str(z["metadata"]))
    report = json.loads(str(z["report"])) if "report" in z.files else {}
    return {"height": h, "mask": mask, "mean": mean.astype(np.float32), "basis": basis,
            "stddev": stddev.astype(np.float32), "explained_variance_ratio": evr,
            "metadata": meta, "report": report}


def save_model(path, *, height: int, mask: np.ndarray, mean: np.ndarray, basis: np.ndarray,
               stddev: np.ndarray, explained_variance_ratio: np.ndarray, metadata: dict,
               report: dict | None = None, basis_dtype: str = "float32") -> Path:
    """Write a model ``.npz`` atomically. ``basis`` (K, N * 7) has unit-norm rows (weighted).

    Args:
        basis_dtype: "float32", "float16" or "int8" (per (component, channel) scale).
    """
    path = Path(path)
    arrays = dict(format=np.array(FORMAT), version=np.array(VERSION), height=np.array(height),
                  mask=np.asarray(mask, bool), mean=np.asarray(mean, np.float32),
                  stddev=np.asarray(stddev, np.float32),
                  explained_variance_ratio=np.asarray(explained_variance_ratio, np.float32),
                  metadata=np.array(json.dumps(metadata)),
                  report=np.array(json.dumps(report or {})))
    b = np.asarray(basis, np.float32)
    if basis_dtype == "float32":
        arrays["basis"] = b
    elif basis_dtype == "float16":
        arrays["basis"] = b.astype(np.float16)
    elif basis_dtype == "int8":
        k = b.shape[0]
        b3 = b.reshape(k, -1, N_CHANNELS)
        scale = np.maximum(np.abs(b3).max(1), 1e-30) / 127.0  # (K, 7)
        arrays["basis"] = np.round(b3 / scale[:, None, :]).astype(np.int8).reshape(k, -1)
        arrays["basis_scale"] = scale.astype(np.float32)
    else:
        raise HackError(f"basis_dtype: expected float32, float16 or int8, found {basis_dtype!r}.")
    return write_npz(path, arrays, compressed=True)
