"""The identity shape space from registered neutral meshes (paper Sec. 4.3, Fig. 11).

:func:`learn_shape` aligns registrations (meshes in the model's vertex order, e.g.
``hack-render register``'s ``registered.obj``) rigidly onto the model's template over
the face and scalp (generalised Procrustes, two rounds), takes their PCA, and writes a
model file whose shape space is the new one: ``template_vertices`` the registrations'
mean, ``shape_components`` / ``shape_std`` the PCA's. Everything else of the base model
that reads beta (personalised expression and pose MLPs, the larynx coefficients) is
carried over exactly within the old space: old beta = P new beta + b0, with P and b0 the
least-squares coordinates of the new components and mean in the old components, folded
into those maps' first linear layers. The model adds its larynx L(beta, eta, tau) to the
shape: registrations with a larynx give a space that holds it too (fit such a model
with a smaller eta, or learn from meshes without it). Compactness and held-out generalisation curves
(leave-one-out folds) go into the file's metadata and a PNG beside it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from hack_render.errors import HackError
from hack_render.geometry import default_model_path
from hack_render.geometry.model_file import load_model_file, save_model_file
from hack_render.io import atomic_path
from hack_render.learn.pca import compactness, fit_pca, generalisation
from hack_render.register.align import umeyama
from hack_render.register.scan import UNITS, detect_units

ALIGN_REGIONS = ("face", "scalp_and_ears")


def read_registration(path: Path, num_vertices: int) -> np.ndarray:
    """(N, 3) vertices in metres of a registered mesh file or a `register` output folder."""
    import trimesh

    units = None
    if path.is_dir():
        rep = path / "report.json"
        if rep.is_file():
            units = json.loads(rep.read_text()).get("scan_scale_m")
        path = path / "registered.obj"
    if not path.is_file():
        raise HackError(f"{path}: no such file. Pass registered meshes (OBJ/PLY in the "
                        "model's vertex order) or `hack-render register` output folders.")
    try:
        mesh = trimesh.load(str(path), process=False, force="mesh", maintain_order=True)
    except Exception as exc:
        raise HackError(f"{path}: cannot read it as a mesh ({exc}).") from exc
    v = np.asarray(mesh.vertices, np.float64)
    if v.shape != (num_vertices, 3):
        raise HackError(f"{path}: expected {num_vertices} vertices in the model's order, found "
                        f"{len(v)}. Register the scan first (`hack-render register`).")
    if not np.isfinite(v).all():
        raise HackError(f"{path}: NaN or infinite vertices.")
    if units is None:
        units = UNITS[detect_units(float(np.ptp(v, 0).max()), path.name)]
    return v * float(units)


def procrustes(meshes: np.ndarray, reference: np.ndarray, ids: np.ndarray,
               rounds: int = 2) -> np.ndarray:
    """Meshes (n, N, 3) moved rigidly onto ``reference`` (N, 3) over vertices ``ids``,
    then onto their own mean (generalised Procrustes)."""
    target = reference
    out = meshes.copy()
    for _ in range(rounds):
        for i in range(len(out)):
            _, R, t = umeyama(out[i, ids], target[ids], with_scale=False)
            out[i] = out[i] @ R.T + t
        target = out.mean(0)
    return out


def shape_curves(x: np.ndarray, max_k: int) -> dict:
    """Compactness of the PCA of ``x`` (n, 3N) and leave-one-out generalisation (mm RMSE
    per vertex, mean over folds) for k = 1..max_k (at most n - 2)."""
    n = len(x)
    comp = compactness(fit_pca(x)).tolist()
    ks = list(range(1, max(1, min(max_k, n - 2)) + 1))
    folds = []
    for i in range(n) if n <= 30 else np.linspace(0, n - 1, 30).astype(int):
        g = generalisation(np.delete(x, i, 0), x[i:i + 1], ks)
        folds.append(g["rmse_mean"])
    gen = np.asarray(folds) * 1000.0
    return {"k": ks, "compactness": comp[: len(ks)], "generalisation_mm_mean": gen.mean(0).tolist(),
            "generalisation_mm_std": gen.std(0).tolist(), "folds": len(folds)}


def learn_shape(paths: list[Path], base_model: Path | None, components: int | None
                ) -> tuple[dict, dict, dict]:
    """(arrays, meta, curves) of a model with the shape space of the registrations."""
    arrays, meta = load_model_file(base_model or default_model_path())
    n_vert = arrays["template_vertices"].shape[0]
    if len(paths) < 3:
        raise HackError(f"learn shape: expected at least 3 registrations, found {len(paths)}.")
    meshes = np.stack([read_registration(p, n_vert) for p in paths])
    regions = [str(r) for r in arrays["region_names"]]
    ids = np.flatnonzero(np.isin(arrays["vertex_region"],
                                 [regions.index(r) for r in ALIGN_REGIONS]))
    aligned = procrustes(meshes, arrays["template_vertices"].astype(np.float64), ids)
    x = aligned.reshape(len(aligned), -1)
    k = min(components or len(x) - 1, len(x) - 1)
    pca = fit_pca(x, k)
    curves = shape_curves(x, k)
    old_dirs = (arrays["shape_components"].astype(np.float64)
                * arrays["shape_std"].astype(np.float64)[:, None, None]).reshape(len(arrays["shape_std"]), -1).T
    new_dirs = (pca.components.astype(np.float64) * pca.std[:, None]).T  # (3N, k)
    mean = pca.mean.astype(np.float64)
    P, *_ = np.linalg.lstsq(old_dirs, new_dirs, rcond=None)  # (S_old, k)
    b0, *_ = np.linalg.lstsq(old_dirs, mean - arrays["template_vertices"].astype(np.float64).ravel(),
                             rcond=None)
    out = dict(arrays)
    out["template_vertices"] = mean.reshape(-1, 3).astype(np.float32)
    out["shape_components"] = pca.components.reshape(k, -1, 3).astype(np.float32)
    out["shape_std"] = pca.std.astype(np.float32)
    for prefix in ("expr", "pose"):
        if f"{prefix}_mlp_w0" in out:
            w0 = out[f"{prefix}_mlp_w0"].astype(np.float64)
            s = w0.shape[1]
            out[f"{prefix}_mlp_w0"] = (w0 @ P[:s]).astype(np.float32)
            out[f"{prefix}_mlp_b0"] = (out[f"{prefix}_mlp_b0"] + w0 @ b0[:s]).astype(np.float32)
    if "larynx_coef_matrix" in out:
        M = out["larynx_coef_matrix"].astype(np.float64)
        s = M.shape[1]
        out["larynx_coef_matrix"] = (M @ P[:s]).astype(np.float32)
        out["larynx_coef_offset"] = (out["larynx_coef_offset"] + M @ b0[:s]).astype(np.float32)
    residual = float(np.linalg.norm(old_dirs @ P - new_dirs) / max(np.linalg.norm(new_dirs), 1e-30))
    meta = dict(meta)
    meta.setdefault("provenance", {})
    meta["provenance"] = dict(meta["provenance"]) if isinstance(meta["provenance"], dict) else {}
    meta["provenance"]["shape"] = (
        f"learned: PCA of {len(paths)} registered meshes (hack-render learn shape), aligned "
        f"rigidly over {', '.join(ALIGN_REGIONS)}; personalised maps and larynx carried over "
        f"through the old shape space (new components outside it: {100 * residual:.1f} % of "
        "their norm, which those maps do not see)")
    meta["learn_shape"] = {"registrations": [str(p) for p in paths], "components": k,
                           "curves": curves}
    return out, meta, curves


def plot_curves(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(8, 3.2))
    ax[0].plot(curves["k"], np.asarray(curves["compactness"]) * 100)
    ax[0].set(xlabel="components", ylabel="variance explained (%)", title="compactness")
    m, s = np.asarray(curves["generalisation_mm_mean"]), np.asarray(curves["generalisation_mm_std"])
    ax[1].errorbar(curves["k"], m, s, capsize=2)
    ax[1].set(xlabel="components", ylabel="held-out RMSE (mm)",
              title=f"generalisation ({curves['folds']} folds)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def learn_shape_cmd(
    registrations: list[Path] = typer.Argument(..., help="Registered meshes (OBJ/PLY in the "
                                               "model's vertex order) or `hack-render "
                                               "register` output folders."),
    output: Path = typer.Option(..., "-o", "--output", help="Model file to write (.npz)."),
    components: int | None = typer.Option(None, "--components", help="Shape components "
                                             "kept (default: all, n - 1)."),
    model_path: Path | None = typer.Option(None, "--model", help="Base model whose other "
                                              "parts are kept (default: built-in)."),
) -> None:
    """Learn the identity shape space (PCA) from registered neutral meshes, with the
    compactness and generalisation curves of the paper's Fig. 11 (OUTPUT.png).

    Example: hack-render learn shape out/reg/* -o my_model.npz
    """
    if output.suffix != ".npz":
        raise HackError(f"-o {output}: expected a .npz model file name.")
    if components is not None and components < 1:
        raise HackError(f"--components: expected >= 1, found {components}.")
    arrays, meta, curves = learn_shape(list(registrations), model_path, components)
    save_model_file(output, arrays, meta)
    plot_curves(curves, output.with_suffix(".png"))
    g = curves["generalisation_mm_mean"]
    typer.echo(f"wrote {output} ({len(curves['k'])} components; compactness "
               f"{100 * curves['compactness'][-1]:.1f} %; held-out RMSE {g[0]:.2f} mm with 1, "
               f"{g[-1]:.2f} mm with {curves['k'][-1]}) and {output.with_suffix('.png')}")
