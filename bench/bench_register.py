"""Registration to scans, in the style of the paper's Table 1 (issue 22; a benchmark, not
a test).

Truth the registering model has not seen (leave-k-out): ``--population`` identities are
drawn from the shipped model's full shape space (beta ~ N(0, I), 100 components: the
ICT-FaceKit identity model the default model is built on); ``--held-out`` of them are set
aside and the shape space is learned again (``hack_render.learn.shape.learn_shape``) from
the others' neutral meshes alone. That leave-k-out model registers scans of the held-out
identities, made by ``hack_render.register.synthetic.make_scan``: re-tessellated (each
triangle split in four, vertices slid along the surface), 0.5 mm noise along the normals,
3 holes of 6-12 mm, a random rotation, translation and unit. Derived data: no real scans.

Per held-out identity, two scans: neutral, and posed (a whole-head rotation within
+-20 deg flexion, +-35 deg axial, +-12 deg lateral shared over the 8 joints, and a random
expression). Each scan is registered with

* ``linear``: the same code and shape space without neck joints (identity and expression
  with a rigid head: ICT-FaceKit's linear model's form),
* ``hack``: all of HACK; its fit before the free-form stage is ``hack (no free-form)``,
* ``paper`` (neutral scans): the paper's protocol preset, no free-form stage.

Reported per configuration, neutral and posed apart: scan-to-mesh mean +- std over scans
(mm; each scan's mean over its points within 1 cm), the same against the noise-free
surface, vertex error against the truth (mm, skin), landmark error, seconds per scan.

    python bench/bench_register.py                          # 10 held out of 60
    python bench/bench_register.py --held-out 3 --population 20 --out /tmp/r.json
    # in parallel, then merged:
    python bench/bench_register.py --threads 1 --identities 0:5 --out /tmp/a.json &
    python bench/bench_register.py --threads 1 --identities 5:10 --out /tmp/b.json
    python bench/bench_register.py --merge /tmp/a.json /tmp/b.json

Writes ``bench/results/register.json``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import ROOT, write_result

from hack_render.geometry import HackModel, distribute_head_rotation, load_default_model
from hack_render.geometry.obj_io import write_mesh
from hack_render.learn.shape import learn_shape
from hack_render.register.fitting import RegisterConfig, model_subsets
from hack_render.register.measure import MeshDistance
from hack_render.register.pipeline import register
from hack_render.register.scan import Scan
from hack_render.register.synthetic import make_scan


def population(model, n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(n, model.num_shape, generator=g)


def leave_out_model(model, betas: torch.Tensor, tmp: Path) -> HackModel:
    """The model with its shape space learned from ``betas``' neutral meshes only."""
    paths = []
    with torch.no_grad():
        for i, b in enumerate(betas):
            # the shape without the larynx: the model adds L(beta, eta, tau) to it
            v = model(beta=b[None], eta=torch.zeros(1)).vertices[0].numpy()
            paths.append(write_mesh(tmp / f"train_{i:03d}.obj", v, model.faces.numpy()))
    arrays, meta, _ = learn_shape(paths, None, None)
    return HackModel(arrays, meta)


def posed_inputs(model, rng: np.random.Generator) -> dict:
    angles = rng.uniform([-20, -35, -12], [20, 35, 12])
    theta = distribute_head_rotation(torch.deg2rad(torch.tensor(angles, dtype=torch.float32)[None]))
    psi = torch.zeros(1, model.num_expressions)
    for k in rng.choice(model.num_expressions, size=3, replace=False):
        psi[0, k] = float(rng.uniform(0.2, 0.7))
    return {"theta": theta, "psi": psi, "angles_deg": angles.tolist()}


def run_one(reg_model, scan_obj, truth_m, clean_m, faces_scan, cfg, lmk_m):
    scan = Scan.from_mesh("bench", scan_obj, faces_scan)
    t0 = time.perf_counter()
    reg = register(reg_model, scan, lmk_m, tuple(range(68)), cfg, progress=False)
    seconds = time.perf_counter() - t0
    rep = reg.report
    skin, cand = model_subsets(reg_model)
    vert = 1000 * np.linalg.norm(reg.vertices - truth_m, axis=1)[skin]
    vert_model = 1000 * np.linalg.norm(reg.model_vertices - truth_m, axis=1)[skin]
    from hack_render.register.fitting import faces_within

    f = faces_within(reg_model.faces.numpy(), cand)
    clean_free = 1000 * MeshDistance(reg.vertices, f).closest(clean_m)[0]
    clean_model = 1000 * MeshDistance(reg.model_vertices, f).closest(clean_m)[0]
    return {
        "status": rep["status"], "seconds": seconds,
        "s2m_mean": rep["scan_to_mesh_mm"]["all"]["mean"],
        "s2m_model_mean": rep["model_only_scan_to_mesh_mm"]["mean"],
        "s2m_face": rep["scan_to_mesh_mm"]["face"].get("mean"),
        "s2m_neck": rep["scan_to_mesh_mm"]["neck"].get("mean"),
        "clean_s2m_mean": float(clean_free[clean_free < 10].mean()),
        "clean_s2m_model_mean": float(clean_model[clean_model < 10].mean()),
        "vertex_mean": float(vert.mean()), "vertex_model_mean": float(vert_model.mean()),
        "landmark_mean": rep["landmarks"]["mean_mm"],
    }


def summarise(rows: list[dict], key: str) -> dict:
    x = np.array([r[key] for r in rows if r.get(key) is not None], np.float64)
    return {"mean": float(x.mean()), "std": float(x.std()), "n": len(x)} if len(x) else {}


def table_of(rows: dict[str, list]) -> dict:
    table = {}
    for key, rs in rows.items():
        name, kind = key.split("/")
        entry = {k: summarise(rs, k) for k in ("s2m_mean", "s2m_face", "s2m_neck",
                                               "clean_s2m_mean", "vertex_mean",
                                               "landmark_mean", "seconds")}
        entry["failed"] = sum(r["status"] != "ok" for r in rs)
        table[f"{name}/{kind}"] = entry
        if name == "hack":
            table[f"hack (no free-form)/{kind}"] = {
                "s2m_mean": summarise(rs, "s2m_model_mean"),
                "clean_s2m_mean": summarise(rs, "clean_s2m_model_mean"),
                "vertex_mean": summarise(rs, "vertex_model_mean")}
    for kind in ("neutral", "posed"):
        lin = table.get(f"linear/{kind}", {}).get("s2m_mean", {}).get("mean")
        hk = table.get(f"hack (no free-form)/{kind}", {}).get("s2m_mean", {}).get("mean")
        if lin and hk:
            table[f"ratio hack/linear ({kind}, no free-form)"] = hk / lin
    return table


def merge(parts: list[Path], out: Path) -> None:
    """One result from several runs over parts of the held-out identities (same protocol)."""
    import json

    data = [json.loads(p.read_text()) for p in parts]
    rows: dict[str, list] = {}
    for d in data:
        for k, rs in d["scans"].items():
            rows.setdefault(k, []).extend(rs)
    protocol = dict(data[0]["protocol"])
    protocol["held_out"] = len({r["identity"] for r in rows.get("hack/neutral", [])})
    protocol["parts"] = [{"file": str(p), "commit": d["commit"], "command": d["command"],
                          "date": d["date"]} for p, d in zip(parts, data)]
    write_result(out, {"protocol": protocol, "table": table_of(rows), "scans": rows})
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--population", type=int, default=60)
    ap.add_argument("--held-out", type=int, default=10)
    ap.add_argument("--identities", default=None, help="START:STOP, a part of the held-out "
                    "identities (run parts in parallel, then --merge their files)")
    ap.add_argument("--merge", type=Path, nargs="+", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "register.json")
    args = ap.parse_args()
    if args.merge:
        merge(args.merge, args.out)
        return
    torch.set_num_threads(args.threads)
    base = load_default_model()
    betas = population(base, args.population, args.seed)
    test, train = betas[: args.held_out], betas[args.held_out:]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        reg_model = leave_out_model(base, train, Path(tmp))
    learn_s = time.perf_counter() - t0
    configs = {"hack": RegisterConfig(), "linear": RegisterConfig(joints=False, larynx=False,
                                                                  free_form=False),
               "paper": RegisterConfig.preset_named("paper", free_form=False)}
    start, stop = (0, len(test)) if args.identities is None else \
        (int(x) for x in args.identities.split(":"))
    rows: dict[str, list] = {}
    for i in range(start, stop):
        b = test[i]
        rng = np.random.default_rng(1000 * args.seed + i)  # the same scans in any part
        for kind in ("neutral", "posed"):
            extra = posed_inputs(base, rng) if kind == "posed" else {}
            with torch.no_grad():
                out = base(beta=b[None], theta=extra.get("theta"), psi=extra.get("psi"))
            truth = out.vertices[0].double().numpy()
            sc = make_scan(base, truth, seed=1000 * args.seed + 10 * i + (kind == "posed"))
            pts = sc.vertices / sc.scale
            truth_scan = sc.truth / sc.scale
            clean = sc.clean / sc.scale
            lmk = truth_scan[base.landmark_indices.numpy()]
            for name, cfg in configs.items():
                if name == "paper" and kind == "posed":
                    continue
                r = run_one(reg_model, pts, truth_scan, clean, sc.faces, cfg, lmk)
                r.update({"identity": i, "scan_vertices": len(pts), "units": sc.units,
                          **({"angles_deg": extra["angles_deg"]} if extra else {})})
                rows.setdefault(f"{name}/{kind}", []).append(r)
                print(f"{i} {kind:7s} {name:6s} s2m {r['s2m_mean']:.3f} (model "
                      f"{r['s2m_model_mean']:.3f}) clean {r['clean_s2m_mean']:.3f} vertex "
                      f"{r['vertex_mean']:.2f} {r['seconds']:.0f} s {r['status']}", flush=True)
    write_result(args.out, {
        "protocol": {"population": args.population, "held_out": stop - start,
                     "registering_model_components": reg_model.num_shape,
                     "learn_shape_s": learn_s, "noise_mm": 0.5, "holes": 3,
                     "retessellated": True, "torch_threads": args.threads,
                     "data": "derived: synthetic scans of identities sampled from the shipped "
                             "model's ICT-FaceKit shape space; no real scans"},
        "table": table_of(rows), "scans": rows})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
