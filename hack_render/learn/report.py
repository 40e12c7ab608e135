"""`hack-render model report`: Fig. 11-style compactness and generalisation curves.

The curves are computed at build time from the training data of each space (they need the
sampled identities, deformation-transfer results and pose fits, which the model file does not
keep) and stored in the model's metadata under ``learn.curves``; this module writes them as
JSON and a 2 x 4 PNG and sets them beside the paper's figures.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hack_render.errors import HackError

#: Paper Sec. 7.1 (Fig. 11): components -> explained variance / held-out RMSE.
PAPER = {"shape": {"explained_variance": {50: 0.955, 200: 0.995}, "rmse_mm": {50: 0.65, 200: 0.26}},
         "larynx": {"explained_variance": {10: 0.952, 30: 0.990}},
         "expression": {"explained_variance": {30: 0.864, 50: 0.937}},
         "pose": {"explained_variance": {6: 0.879}}}
SPACES = ("shape", "larynx", "expression", "pose")


def model_curves(meta: dict) -> dict:
    """The curves stored by the v2 builder; HackError if the model has none."""
    curves = meta.get("learn", {}).get("curves")
    if not curves:
        raise HackError("this model has no learned-component curves (metadata 'learn.curves'); "
                        "build it with `hack-render learn model`.")
    return curves


def summarise(curves: dict) -> dict:
    """Our values at the paper's component counts, beside the paper's."""
    out = {}
    for space in SPACES:
        c = curves.get(space, {})
        ev = c.get("explained_variance", [])
        row = {"ours_explained_variance": {}, "paper": PAPER[space]}
        for k in PAPER[space]["explained_variance"]:
            row["ours_explained_variance"][k] = ev[min(k, len(ev)) - 1] if ev else None
        gen = c.get("generalisation") or c.get("reconstruction")
        if gen:
            row["ours_rmse_mm_at"] = {int(k): float(r) * 1e3 for k, r in zip(gen["k"], gen["rmse_mean"])}
        out[space] = row
    return out


def write_report(meta: dict, out_dir: str | Path) -> tuple[Path, Path]:
    """Write report.json and report.png into out_dir; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = model_curves(meta)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    js = out_dir / "report.json"
    js.write_text(json.dumps({"curves": curves, "summary": summarise(curves)}, indent=1, default=float))
    fig, axes = plt.subplots(2, 4, figsize=(16, 7))
    for col, space in enumerate(SPACES):
        c = curves.get(space, {})
        ev = np.asarray(c.get("explained_variance", []), float)
        ax = axes[0, col]
        ax.plot(np.arange(1, len(ev) + 1), ev * 100, "r-", label="ours")
        for k, val in PAPER[space]["explained_variance"].items():
            ax.plot([k], [val * 100], "ko", label="paper" if k == min(PAPER[space]["explained_variance"]) else None)
        ax.set_title(f"{space}: compactness")
        ax.set_xlabel("components")
        ax.set_ylabel("explained variance %")
        ax.legend()
        ax = axes[1, col]
        gen = c.get("generalisation") or c.get("reconstruction")
        if gen:
            m, s = np.asarray(gen["rmse_mean"]) * 1e3, np.asarray(gen["rmse_std"]) * 1e3
            ax.errorbar(gen["k"], m, yerr=s, fmt="b.-", label="held-out" if "generalisation" in c else "training")
            if space == "shape":
                ax.plot(list(PAPER["shape"]["rmse_mm"]), list(PAPER["shape"]["rmse_mm"].values()), "ko", label="paper")
            ax.legend()
        ax.set_title(f"{space}: RMSE")
        ax.set_xlabel("components")
        ax.set_ylabel("RMSE mm")
    fig.tight_layout()
    png = out_dir / "report.png"
    fig.savefig(png, dpi=80)
    plt.close(fig)
    return js, png
