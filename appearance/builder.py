"""Build an appearance model from a folder of texture sets, memory-bounded, with a report.

    hack-render learn appearance DIR -o model.npz [--height 256] [--components K]

DIR holds one folder per subject (layout in :mod:`appearance.texture_io`). The build:

1. reads each subject once, validates it, resamples it to the model's atlas height and
   encodes its valid texels as (N, 7) channels (diffuse, specular, roughness, normal
   slopes; :mod:`appearance.model`), appended to an on-disk float32 matrix X (S x D) in a
   temporary folder: memory holds one subject at a time;
2. accumulates per-block uncentred Gram matrices X_b X_b^T (S x S, float64) over column
   chunks of X; from them any subset's centred, block-weighted Gram follows exactly,
   so the full model and the 90/10 held-out split need no second pass over the images;
3. eigendecomposes the weighted centred Gram (blocks weighted to equal total variance)
   and forms the components X^T U / sqrt(lambda) chunk by chunk.

Peak memory is O(S^2 + chunk * S) plus one subject, independent of resolution (chunks
are sized to ~128 MB of float64, :func:`chunk_for`); the
disk holds X (S x D float32; 500 subjects at 1024 x 2048 atlases take ~10 GB).
The report (JSON + PNG) gives explained variance against k and held-out errors against
k: RMSE of linear RGB, mean CIEDE2000 of the diffuse map, mean angular error of normals.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from appearance.colour_space import delta_e2000
from appearance.model import BLOCKS, N_CHANNELS, normals_to_slopes, save_model
from appearance.texture_io import read_texture_set
from appearance.uv import rasterize_layout
from hack_render.errors import HackError
from hack_render.io import atomic_path, write_json

DEFAULT_ROUGHNESS = 0.6  # perceptual; used only when no subject has a roughness map


def resample(img: np.ndarray, height: int) -> np.ndarray:
    """(h, 2h, C) -> (H, 2H, C), area-averaged down / bilinear up (torch.interpolate)."""
    if img.shape[0] == height:
        return img.astype(np.float32, copy=False)
    t = torch.from_numpy(np.ascontiguousarray(img, np.float32)).permute(2, 0, 1)[None]
    mode = "area" if img.shape[0] > height else "bilinear"
    kw = {} if mode == "area" else {"align_corners": False}
    out = torch.nn.functional.interpolate(t, size=(height, 2 * height), mode=mode, **kw)
    return out[0].permute(1, 2, 0).numpy()


def encode_subject(maps: dict[str, np.ndarray], height: int, valid: np.ndarray,
                   roughness_default: float = DEFAULT_ROUGHNESS) -> np.ndarray:
    """One subject's maps -> (N * 7,) float32 vector over the valid texels ``valid``."""
    h = height
    out = np.empty((len(valid), N_CHANNELS), np.float32)
    flat = lambda a: a.reshape(-1, a.shape[-1])[valid]
    out[:, BLOCKS["diffuse"]] = flat(resample(maps["diffuse"], h))
    out[:, BLOCKS["specular"]] = flat(resample(maps["specular"], h))
    if "roughness" in maps:
        out[:, BLOCKS["roughness"]] = flat(resample(maps["roughness"], h))
    else:
        out[:, BLOCKS["roughness"]] = roughness_default
    out[:, BLOCKS["normal"]] = normals_to_slopes(flat(resample(maps["normal"], h)))
    return out.reshape(-1)


@dataclass
class GramStore:
    """The training matrix on disk and its per-block uncentred Gram matrices."""

    x: np.memmap            # (S, D) float32
    gram: np.ndarray        # (n_blocks, S, S) float64
    block_cols: list        # per block: column mask over the 7 channels
    chunk_texels: int

    def chunks(self):
        n_tex = self.x.shape[1] // N_CHANNELS
        for s in range(0, n_tex, self.chunk_texels):
            e = min(n_tex, s + self.chunk_texels)
            yield slice(s * N_CHANNELS, e * N_CHANNELS)


def _block_of_channel() -> np.ndarray:
    b = np.zeros(N_CHANNELS, np.int64)
    for i, sl in enumerate(BLOCKS.values()):
        b[sl] = i
    return b


def chunk_for(n_subjects: int, budget_mb: float = 128.0) -> int:
    """Texels per column chunk so one float64 chunk of all subjects fits ``budget_mb``."""
    return max(256, int(budget_mb * 2 ** 20 / (n_subjects * N_CHANNELS * 8)))


def accumulate_gram(x: np.ndarray, chunk_texels: int | None = None) -> GramStore:
    """Per-block uncentred Gram matrices of ``x`` (S, D), reading it in column chunks.

    Args:
        chunk_texels: texels per chunk (default: :func:`chunk_for`, ~128 MB per chunk).
    """
    s = x.shape[0]
    chunk_texels = chunk_texels or chunk_for(s)
    blocks = _block_of_channel()
    gram = np.zeros((len(BLOCKS), s, s))
    store = GramStore(x, gram, [blocks == i for i in range(len(BLOCKS))], chunk_texels)
    for sl in store.chunks():
        c = np.asarray(x[:, sl], np.float64).reshape(s, -1, N_CHANNELS)
        for i, cols in enumerate(store.block_cols):
            v = c[:, :, cols].reshape(s, -1)
            gram[i] += v @ v.T
    return store


def centred_gram(gram: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(n_blocks, n, n) Gram of the rows ``rows``, centred on their own mean, per block."""
    g = gram[:, rows][:, :, rows]
    r = g.mean(2, keepdims=True)
    return g - r - np.swapaxes(r, 1, 2) + g.mean((1, 2), keepdims=True)


@dataclass
class PCAResult:
    """PCA of a subset: weights, eigenpairs (descending) and the subset's rows."""

    rows: np.ndarray        # (n,) training subject indices
    weights: np.ndarray     # (n_blocks,) block weights w_b
    eigvals: np.ndarray     # (n - 1,) of the weighted centred Gram
    eigvecs: np.ndarray     # (n, n - 1)
    block_var: np.ndarray   # (n_blocks,) total variance per block


def pca_from_gram(gram: np.ndarray, rows: np.ndarray) -> PCAResult:
    """Weighted PCA of the subjects ``rows`` from per-block Gram matrices."""
    gc = centred_gram(gram, rows)
    n = len(rows)
    block_var = np.array([np.trace(g) for g in gc]) / max(n - 1, 1)
    w = 1.0 / np.sqrt(np.maximum(block_var, 1e-30))
    w = np.where(block_var > 1e-20, w, 0.0)  # constant blocks (e.g. no roughness) get no weight
    gw = np.einsum("b,bij->ij", w ** 2, gc)
    lam, u = np.linalg.eigh(gw)
    order = np.argsort(lam)[::-1][: max(n - 1, 0)]
    lam, u = np.clip(lam[order], 0, None), u[:, order]
    keep = lam > lam.max(initial=0) * 1e-12
    return PCAResult(rows, w, lam[keep], u[:, keep], block_var)


def components(store: GramStore, pca: PCAResult, k: int, mean: np.ndarray) -> np.ndarray:
    """(k, D) basis b_k with x = mean + sum_k c_k b_k, c_k ~ N(0, sigma_k^2).

    b_k = (X_c^T U_k) / sqrt(lambda_k) per block; the weighted version is unit norm.
    """
    u = pca.eigvecs[:, :k] / np.sqrt(pca.eigvals[:k])
    out = np.empty((k, store.x.shape[1]), np.float32)
    rows = pca.rows
    for sl in store.chunks():
        xc = np.asarray(store.x[rows, sl], np.float64) - mean[sl]
        out[:, sl] = (u.T @ xc).astype(np.float32)
    # With X_w = X_c W and G_w = U Lambda U^T, training coefficients are
    # c_i = Lambda^(1/2) U_i and x_c,i = W^-1 X_w^T U Lambda^(-1/2) c_i = X_c^T U Lambda^(-1/2) c_i.
    return out


def subset_mean(store: GramStore, rows: np.ndarray) -> np.ndarray:
    """(D,) float64 mean of the rows ``rows``."""
    m = np.zeros(store.x.shape[1])
    for sl in store.chunks():
        m[sl] = np.asarray(store.x[rows, sl], np.float64).mean(0)
    return m


def subject_folders(root) -> list[Path]:
    """Subject folders of ``root`` (sorted); error if there are none. A sub-folder holding
    its maps in ``textures/`` (a `hack-render register` output folder of a coloured scan)
    counts as that folder; one of an uncoloured scan (no maps) is left out."""
    root = Path(root)
    if not root.is_dir():
        raise HackError(f"{root}: expected a folder of subject folders, found no folder.")
    subs = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    # `hack-render register`'s output: one folder per scan, its baked maps in textures/
    subs = [p / "textures" if (p / "textures").is_dir() and not any(p.glob("diffuse.*"))
            else p for p in subs]
    subs = [p for p in subs if not ((p / "registered.obj").is_file()
                                    and not any(p.glob("diffuse.*")))]
    if len(subs) < 3:
        raise HackError(f"{root}: expected at least 3 subject folders (each with diffuse, "
                        f"specular and normal maps), found {len(subs)}.")
    return subs


def load_training_matrix(folders: list[Path], height: int, workdir: Path, progress=True):
    """Encode every subject into an on-disk (S, D) float32 matrix; returns it and the mask."""
    lay = rasterize_layout(height)
    valid = np.flatnonzero(lay.mask)
    d = len(valid) * N_CHANNELS
    x = np.lib.format.open_memmap(workdir / "X.npy", mode="w+", dtype=np.float32,
                                  shape=(len(folders), d))
    has_rough = None
    for i, f in enumerate(tqdm(folders, desc="read subjects", disable=not progress)):
        maps = read_texture_set(f)
        hr = "roughness" in maps
        if has_rough is None:
            has_rough = hr
        elif hr != has_rough:
            raise HackError(f"{f}: expected {'a' if has_rough else 'no'} roughness map like "
                            f"{folders[0].name}, found {'one' if hr else 'none'}. Give every "
                            f"subject a roughness map, or none.")
        x[i] = encode_subject(maps, height, valid)
    x.flush()
    return x, lay.mask, bool(has_rough)


def heldout_errors(store: GramStore, train: np.ndarray, test: np.ndarray, ks: list[int],
                   mask_valid: int) -> dict:
    """Generalisation errors of the PCA on ``train`` for the ``test`` subjects, per k."""
    pca = pca_from_gram(store.gram, train)
    ks = [k for k in ks if k <= len(pca.eigvals)]
    kmax = max(ks)
    mean = subset_mean(store, train)
    u = pca.eigvecs[:, :kmax] / np.sqrt(pca.eigvals[:kmax])  # (n_train, kmax)
    wch = pca.weights[_block_of_channel()]
    # coefficients of the test subjects: c = U^T Xw_train (xw_test - mean_w) / sqrt(lambda)
    coef = np.zeros((len(test), kmax))
    for sl in store.chunks():
        w = np.tile(wch, (sl.stop - sl.start) // N_CHANNELS)
        xt = (np.asarray(store.x[train, sl], np.float64) - mean[sl]) * w
        xs = (np.asarray(store.x[test, sl], np.float64) - mean[sl]) * w
        coef += (xs @ xt.T) @ u
    sse = np.zeros(len(ks))
    de = np.zeros(len(ks))
    ang = np.zeros(len(ks))
    n_tex = 0
    for sl in store.chunks():
        xt = np.asarray(store.x[train, sl], np.float64) - mean[sl]
        basis = u.T @ xt  # (kmax, chunk) unweighted
        xs = np.asarray(store.x[test, sl], np.float64)
        n = (sl.stop - sl.start) // N_CHANNELS
        n_tex += n
        truth = xs.reshape(len(test), n, N_CHANNELS)
        for j, k in enumerate(ks):
            rec = (mean[sl] + coef[:, :k] @ basis[:k]).reshape(len(test), n, N_CHANNELS)
            d_t, d_r = truth[..., BLOCKS["diffuse"]], np.clip(rec[..., BLOCKS["diffuse"]], 0, 1)
            sse[j] += ((d_t - d_r) ** 2).sum()
            de[j] += delta_e2000(d_t.reshape(-1, 3), d_r.reshape(-1, 3)).sum()
            nt = _unit(truth[..., BLOCKS["normal"]])
            nr = _unit(rec[..., BLOCKS["normal"]])
            ang[j] += np.degrees(np.arccos(np.clip((nt * nr).sum(-1), -1, 1))).sum()
    cnt = len(test) * n_tex
    return {"k": ks, "rmse_linear_rgb": np.sqrt(sse / (cnt * 3)).round(5).tolist(),
            "mean_ciede2000": (de / cnt).round(4).tolist(),
            "mean_normal_angle_deg": (ang / cnt).round(4).tolist(),
            "n_train": len(train), "n_test": len(test)}


def _unit(slopes):
    n = np.concatenate([slopes, np.ones_like(slopes[..., :1])], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def k_grid(kmax: int) -> list[int]:
    """Component counts to evaluate: 0, 1, 2, 5, 10, 20, ... up to kmax."""
    ks = [k for k in (0, 1, 2, 3, 5, 8, 10, 15, 20, 30, 40, 50, 75, 100, 150, 200, 300, 400)
          if k <= kmax]
    return sorted(set(ks + [kmax]))


def build_model(root, out, height: int = 256, n_components: int | None = None,
                basis_dtype: str = "float32", holdout: float = 0.1, seed: int = 0,
                metadata: dict | None = None, workdir=None, progress: bool = True,
                chunk_texels: int | None = None) -> dict:
    """Build a model file from the subject folders in ``root``; returns the report.

    Args:
        root: folder of subject folders. out: model ``.npz`` path (a ``.json`` report and a
        ``.png`` plot are written beside it).
        height: model atlas height H (maps are H x 2H); inputs of any size are resampled.
        n_components: components kept (default all, S - 1).
        basis_dtype: storage of the basis: float32 (exact), float16 or int8.
        holdout: fraction of subjects held out for the generalisation curves (0 = none).
        metadata: extra provenance written into the model file.
    """
    t0 = time.perf_counter()
    folders = subject_folders(root)
    out = Path(out)
    if out.suffix != ".npz":
        raise HackError(f"output: expected a .npz path, found {out}.")
    tmp_parent = workdir or os.environ.get("TMPDIR") or out.parent.resolve()
    Path(tmp_parent).mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".appearance-build-", dir=tmp_parent) as wd:
        x, mask, has_rough = load_training_matrix(folders, height, Path(wd), progress)
        store = accumulate_gram(x, chunk_texels)
        rows = np.arange(len(folders))
        pca = pca_from_gram(store.gram, rows)
        kmax = len(pca.eigvals)
        k = kmax if n_components is None else min(int(n_components), kmax)
        mean = subset_mean(store, rows)
        basis = components(store, pca, k, mean)
        n = len(rows)
        stddev = np.sqrt(pca.eigvals / max(n - 1, 1))
        evr_all = pca.eigvals / pca.eigvals.sum()
        report = {"n_subjects": n, "height": height, "n_components": k,
                  "explained_variance_ratio": evr_all.round(6).tolist(),
                  "cumulative_explained_variance": np.cumsum(evr_all).round(6).tolist(),
                  "block_weights": dict(zip(BLOCKS, pca.weights.round(6).tolist())),
                  "block_total_variance": dict(zip(BLOCKS, pca.block_var.tolist())),
                  "roughness_modelled": has_rough}
        if holdout > 0 and n >= 10:
            rng = np.random.default_rng(seed)
            perm = rng.permutation(n)
            n_test = max(1, int(round(holdout * n)))
            test, train = np.sort(perm[:n_test]), np.sort(perm[n_test:])
            report["heldout"] = heldout_errors(store, train, test, k_grid(len(train) - 1),
                                               int(mask.sum()))
            report["heldout"]["split_seed"] = seed
        report["build_seconds"] = round(time.perf_counter() - t0, 2)
    meta = {"kind": "unknown", "source": str(root), "n_subjects": n,
            "builder": "hack-render learn appearance", "basis_dtype": basis_dtype,
            "roughness_modelled": has_rough}
    meta.update(metadata or {})
    save_model(out, height=height, mask=mask, mean=mean, basis=basis, stddev=stddev[:k],
               explained_variance_ratio=evr_all[:k], metadata=meta, report=report,
               basis_dtype=basis_dtype)
    write_report(report, out.with_suffix(".report.json"), out.with_suffix(".report.png"))
    return report


def write_report(report: dict, json_path: Path, png_path: Path) -> None:
    """Write the report JSON and its plot (explained variance; held-out errors vs k)."""
    write_json(json_path, report, indent=1)
    plot_report(report, png_path)


def plot_report(report: dict, png_path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cum = report["cumulative_explained_variance"]
    ho = report.get("heldout")
    fig, axes = plt.subplots(1, 4 if ho else 1, figsize=(18 if ho else 5, 3.8))
    axes = np.atleast_1d(axes)
    axes[0].plot(np.arange(1, len(cum) + 1), cum, "r-")
    axes[0].set(xlabel="components k", ylabel="explained variance (cumulative)",
                title=f"compactness ({report['n_subjects']} subjects)", ylim=(0, 1.01))
    axes[0].grid(alpha=0.3)
    if ho:
        for ax, key, lab in ((axes[1], "rmse_linear_rgb", "RMSE linear RGB"),
                             (axes[2], "mean_ciede2000", "mean CIEDE2000 (diffuse)"),
                             (axes[3], "mean_normal_angle_deg", "mean normal error (deg)")):
            ax.plot(ho["k"], ho[key], "b.-")
            ax.set(xlabel="components k", ylabel=lab,
                   title=f"held-out ({ho['n_test']} of {ho['n_test'] + ho['n_train']})")
            ax.grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
