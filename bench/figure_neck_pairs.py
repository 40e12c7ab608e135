"""Before/after renders of the pose subset's worst head flexion/extension pairs (issue 60:
"the renders of the five worst poses before and after"; a figure, not a test).

On ``bench/bench_pose_arap.py``'s subset (``--poses`` poses of seed ``--seed``, the
template and ``--identities - 1`` identities), neutral: the ``--count`` pairs of the head
flexion/extension family where the ``--before`` model is furthest above the pose's
physical lower bound (:func:`hack_render.geometry.deformation.model_stretch_bound`), each
posed by both models, ray cast grey (no Monte Carlo noise) from ``--yaw`` / ``--pitch``
(the throat seen from in front and below); ``--active-only``: among the poses within the
neck's active range. Rows: before, after; one column per pair, its stretch above the bound
and folded triangles printed and written beside the image (``.json``).

    python bench/figure_neck_pairs.py --before REV_OR_FILE --after hack_render/data/hack_default.npz \\
        --out docs/images/neck_v8_flexion.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pose_gate import add_subset_arguments, subset
from bench_pose_space import model_from_git

from hack_render.geometry.anatomy import within_active_range
from hack_render.geometry.deformation import (
    deformation_stats,
    model_stretch_bound,
    rigid_anchors,
    skin_topology,
)
from hack_render.geometry.lbs import chain_parents, local_rotations, rigid_transforms
from hack_render.geometry.model import HackModel
from hack_render.render.mesh_views import MeshViews
from scenes.cameras import orbit


def load(spec: str) -> HackModel:
    """A float64 model from a file or a git revision of the default model."""
    return (HackModel.from_file(spec) if Path(spec).is_file() else model_from_git(spec)).double()


def pairs(model, betas, theta, topo, anchors) -> np.ndarray:
    """(I, P) each pair's largest stretch above its bound, and (I, P) folded triangles."""
    gap, folded = [], []
    rot = local_rotations(theta, theta.new_zeros(len(theta), 3))
    for b in betas:
        person = model.personalize(b[None])
        with torch.no_grad():
            rest = person().vertices[0]
            posed = person(theta=theta).vertices
        j = person.joints.expand(len(theta), -1, -1)
        _, rel = rigid_transforms(rot, torch.cat([j[:, :1], j], 1), chain_parents(model.parents))
        st = deformation_stats(rest, posed, rel[..., :3, :3], topo)
        bound = model_stretch_bound(model, b[None], theta, None, topo, anchors)
        gap.append((st.stretch - bound).numpy())
        folded.append(st.folded.numpy())
    return np.stack(gap), np.stack(folded)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_subset_arguments(ap)
    ap.add_argument("--before", required=True, help="model file or git revision")
    ap.add_argument("--after", required=True, help="model file or git revision")
    ap.add_argument("--family", default="head_x")
    ap.add_argument("--count", type=int, default=5)
    ap.add_argument("--active-only", action="store_true", help="only poses within the "
                    "neck's active range (anatomy.within_active_range)")
    ap.add_argument("--yaw", type=float, default=-40.0)
    ap.add_argument("--pitch", type=float, default=-35.0)
    ap.add_argument("--size", type=int, default=320)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    models = [load(args.before), load(args.after)]
    topo = skin_topology(models[0])
    anchors = rigid_anchors(models[0], topo)
    names, theta, fam_of, betas = subset(args)
    keep = fam_of == names.index(args.family)
    if args.active_only:
        keep &= within_active_range(theta.numpy())
    sel = np.flatnonzero(keep)
    th = theta[sel].double()
    betas = betas.double()
    stats = [pairs(m, betas, th, topo, anchors) for m in models]
    worst = np.argsort(-stats[0][0], axis=None)[:args.count]
    cam = orbit(args.size, args.size, 50.0, args.yaw, args.pitch)
    faces = models[0].faces.numpy()
    rows, record = [], []
    for k, m in enumerate(models):
        tiles = []
        for flat in worst:
            i, p = np.unravel_index(flat, stats[0][0].shape)
            with torch.no_grad():
                v = m(beta=betas[i:i + 1].double(), theta=th[p:p + 1]).vertices[0].numpy()
            views = MeshViews(v, faces, width=args.size, height=args.size)
            img = views.render(cam)
            rgb = np.where(img[..., 3:] > 0, img[..., :3], 1.0) ** (1 / 2.2)
            tiles.append((255 * np.clip(rgb, 0, 1)).astype(np.uint8))
            if k == 0:
                head = np.rad2deg(th[p].sum(0).numpy())
                record.append({"identity": int(i), "pose": int(sel[p]),
                               "head_euler_sum_deg": [round(float(x), 1) for x in head]})
            record[len(tiles) - 1][f"{'before' if k == 0 else 'after'}"] = {
                "above_bound": round(float(stats[k][0][i, p]), 3),
                "folded_triangles": int(stats[k][1][i, p])}
        rows.append(np.concatenate(tiles, 1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, 0)).save(args.out)
    args.out.with_suffix(".json").write_text(json.dumps(
        {"before": args.before, "after": args.after, "family": args.family,
         "active_only": args.active_only, "camera": {"yaw": args.yaw, "pitch": args.pitch},
         "pairs": record}, indent=1))
    for r in record:
        print(r)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
