"""Geometry forward cost, measured fairly: against smplx's ``lbs`` on the same arrays and
against a memory floor that reads the bytes the forward actually reads (issue 21, part 4).

Sides, timed interleaved (one call of each per round, the order rotating every round, so
load on a shared machine hits all of them alike), ``--repeats`` rounds; each is reported as
the median with its range (min..max) over the rounds, and ratios of medians:

* ``hack``: ``HackModel.forward`` with every term on: shape, expressions, generic and
  personalised pose correctives, personalised expressions, larynx (eta, tau), LBS.
* ``smplx``: ``smplx.lbs.lbs`` (smplx 0.1.28, a bench-only dependency: ``pip install
  smplx``) on the same arrays: v_template = the template, shapedirs = the shape and
  expression blendshapes (betas = [beta, psi]), posedirs = the dense (72, 3N) pose basis
  (SMPL's layout; the zeros off the neck included), J_regressor = the joint regressor with
  the root row (c7-t1) first, parents = the chain, lbs_weights = the skinning weights. It
  has no personalised or larynx terms: the HACK side does strictly more work.
* ``hack_one_thread`` (B = 1 only): the same forward with its helper thread off
  (``HackModel.overlap_products = False``: every product on the calling thread, as before
  the helper), so that one run shows what the helper gives; ``hack`` takes the helper only
  where a core is idle (``threads.spare_core``), as a user's forward does.
* ``floor``: one (B, K) @ (K, 3N) float32 product over a buffer as large as the bytes the
  HACK forward reads for these inputs (:func:`bytes_read`: the basis rows it uses, as the
  forward lays them out, the personalised components of the used rows, the pose
  correctives, larynx maps, blended vertices' skinning weights and template), i.e. reading
  those bytes once.
* ``smplx_floor``: the same over a buffer as large as the bytes smplx's ``lbs`` reads
  (:func:`smplx_bytes`): each side's time over its own floor says which side's gap is
  its overhead and which its bytes.

Configurations: B = 1 and B = 64 distinct identities with dense random psi (every row of
every basis read), B = 64 rows of one identity (a sequence or a multi-view fit; the
personalised bases are built once), and B = 1 with a FACS expression (sparse psi); all
with every shape component (100), and B = 1 with 20 (the dataset's and the fitter's
identity; smplx gets the same 20 shape columns), dense psi and a FACS expression.

``--hogs N`` runs the whole table beside N CPU-bound processes (``while True: pass``,
started and stopped by this script), the loaded case of issue 65.

    python bench/bench_geometry.py [--repeats 21] [--threads N] [--spin] [--clock cpu]
                                   [--hogs N] [--out bench/results/bench_geometry.json]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

# Idle OpenMP workers sleep instead of spinning (set before torch loads its OpenMP runtime;
# --spin keeps the runtime's default). On a machine whose cores other processes also use,
# spinning workers make every parallel region wait a scheduler time slice for a descheduled
# thread, and a forward of many regions measures the scheduler, not the code (measured on
# 2 shared cores: HACK 62 ms vs smplx 70 ms at B = 1 spinning, 8.0 vs 9.4 ms sleeping).
if "--spin" not in sys.argv:
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from provenance import write_result

from hack_render.geometry import distribute_head_rotation, load_default_model
from hack_render.geometry.lbs import local_rotations

try:
    from smplx.lbs import lbs as smplx_lbs
except ImportError as err:  # bench-only dependency
    raise SystemExit("bench_geometry needs smplx (a bench-only dependency): pip install smplx"
                     ) from err


def smplx_arrays(model, num_shape: int | None = None) -> dict[str, torch.Tensor]:
    """The HACK model's arrays in smplx ``lbs``'s layout (see the module docstring), with
    the first ``num_shape`` shape components (default: all)."""
    n, e = model.num_vertices, model.num_expressions
    s = model.num_shape if num_shape is None else num_shape
    rows = model.expr_shape_basis  # (E + S, 3N): expressions first
    dirs = torch.cat([rows[e:e + s], rows[:e]], 0)  # smplx order: [beta, psi]
    shapedirs = dirs.view(-1, n, 3).permute(1, 2, 0).contiguous()  # (N, 3, S + E)
    p = 9 * model.num_joints
    posedirs = torch.zeros(p, n, 3)
    posedirs[:, model.pose_columns] = model.pose_basis_columns.view(p, -1, 3)
    reg = torch.cat([model.joint_regressor[:1], model.joint_regressor], 0)  # root at c7-t1
    parents = torch.tensor([-1] + [q + 1 for q in model.parents])
    return {"v_template": model.template[None], "shapedirs": shapedirs,
            "posedirs": posedirs.view(p, -1), "J_regressor": reg, "parents": parents,
            "lbs_weights": model.skinning_weights}


def bytes_read(model, beta: torch.Tensor, psi: torch.Tensor,
               theta: torch.Tensor | None = None) -> int:
    """Bytes of model buffers the forward reads for these inputs (float32, index arrays
    excluded), as the forward reads them: the template and the given betas' shape rows;
    for the expression rows with a nonzero weight, at B = 1 their rows of
    ``expr_psi_rows`` (generic rows on the moved vertices, personal mean folded in) and of
    M_E's components, otherwise their generic rows (3N wide) and personal mean and
    components (once for a shared identity or a batch); the pose correctives (M_P's basis
    at w = b2 when its MLP is constant for these betas, else its mean and components, and
    the generic columns when not folded); the larynx maps and the blended vertices'
    skinning weights; and the flexion block's rows (format 5) of the hats active in
    ``theta`` (their first ``1 + beta`` terms)."""
    f = 4
    n3 = model.expr_shape_basis.shape[1]
    used_e = int(psi.ne(0).any(0).sum())
    total = (beta.shape[1] * n3 + model.template.numel()) * f
    ep = model.expr_personal
    if ep is not None:
        _, c, k = ep.rows.shape
        total += used_e * c * k * f
        if psi.shape[0] == 1 and model.expr_psi_rows is not None:
            total += used_e * model.expr_psi_rows.shape[1] * f
        else:
            total += used_e * (n3 + k) * f
    else:
        total += used_e * n3 * f
    pp = model.pose_personal
    if pp is not None:
        if pp.mlp.weights(beta)[1]:
            total += model.pose_bias_basis.numel() * f
        else:
            total += (pp.rows.numel() + pp.mean.numel()) * f
    if model.has_pose_basis and not model.pose_folded:
        total += model.pose_basis_columns.numel() * f
    if model.has_larynx:
        total += model.larynx_maps.numel() * f
    total += model.blended_weights.numel() * f
    fb = getattr(model, "flex", None)
    if fb is not None and theta is not None:
        rot = local_rotations(theta, theta.new_zeros(theta.shape[0], 3))[:, 1:]
        hats = int((fb.weights(rot).amax(0) > 0).sum())
        total += hats * min(1 + beta.shape[1], fb.num_terms) * fb.basis.shape[-1] * f
    return total


def floor_buffer(nbytes: int, width: int) -> torch.Tensor:
    rows = -(-nbytes // (4 * width))
    return torch.randn(rows, width)


def smplx_bytes(sx: dict) -> int:
    """Bytes of the arrays smplx's ``lbs`` reads (float32): shape and expression
    directions, the dense pose directions, the joint regressor, weights and template."""
    return 4 * sum(sx[k].numel() for k in ("v_template", "shapedirs", "posedirs",
                                             "J_regressor", "lbs_weights"))


#: the clock of :func:`interleaved`: wall time, or (``--clock cpu``) this process's CPU
#: time, every thread's (with one thread, the work without the waits other jobs cause)
CLOCK = {"wall": time.perf_counter, "cpu": time.process_time}


def one_thread(model, kw: dict):
    """The forward with its helper thread off (``HackModel.overlap_products``)."""
    model.overlap_products = False
    try:
        return model(**kw)
    finally:
        model.overlap_products = True


def interleaved(fns: dict, repeats: int, clock: str = "wall") -> dict[str, list[float]]:
    """Per side, the times of ``repeats`` rounds; one call per side per round, the
    order rotating, after one warm-up call each."""
    now = CLOCK[clock]
    names = list(fns)
    for f in fns.values():
        f()
    times = {k: [] for k in names}
    for r in range(repeats):
        order = names[r % len(names):] + names[:r % len(names)]
        for k in order:
            t0 = now()
            fns[k]()
            times[k].append(now() - t0)
    return times


PRINTED: list[str] = []


def say(text: str) -> None:
    """Print, and keep the line for the result file (the docs page shows them)."""
    print(text)
    PRINTED.append(text)


def summary(ts: list[float]) -> dict:
    return {"median_ms": 1e3 * statistics.median(ts), "min_ms": 1e3 * min(ts),
            "max_ms": 1e3 * max(ts), "n": len(ts)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=21, help="rounds (>= 15 for the medians)")
    ap.add_argument("--out", type=Path, default=Path("bench/results/bench_geometry.json"))
    ap.add_argument("--threads", type=int, default=None,
                    help="torch CPU threads (default: torch's own choice)")
    ap.add_argument("--clock", choices=tuple(CLOCK), default="wall",
                    help="wall time (default) or the process's CPU time (all threads)")
    ap.add_argument("--spin", action="store_true",
                    help="keep OpenMP's default spin-waiting (default: OMP_WAIT_POLICY=PASSIVE)")
    ap.add_argument("--hogs", type=int, default=0,
                    help="CPU-bound processes to run beside the whole table (default 0)")
    args = ap.parse_args()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.hogs)]
    try:
        run(args)
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def run(args) -> None:
    """The table (see the module docstring), written to ``args.out``."""
    if args.threads:
        torch.set_num_threads(args.threads)
    model = load_default_model()
    sx_all = {s: smplx_arrays(model, s) for s in (model.num_shape, 20)}
    gen = torch.Generator().manual_seed(0)
    say(f"torch {torch.__version__}, threads {torch.get_num_threads()}, repeats {args.repeats}, "
          f"clock {args.clock}, OMP_WAIT_POLICY {os.environ.get('OMP_WAIT_POLICY', 'unset')}")
    say(f"CPU-bound processes beside: {args.hogs}; 1-min load average {os.getloadavg()[0]:.1f}")
    results = {"repeats": args.repeats, "threads": torch.get_num_threads(), "clock": args.clock,
               "hogs": args.hogs,
               "torch": torch.__version__,
               "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY", "default (spin)"),
               "load_average_1min_before": os.getloadavg()[0], "configs": {}}
    S = model.num_shape
    configs = [("B=1", 1, False, False, S), ("B=64", 64, False, False, S),
               ("B=64 one identity", 64, True, False, S), ("B=1 FACS expression", 1, False, True, S),
               ("B=1 S=20", 1, False, False, 20), ("B=1 S=20 FACS expression", 1, False, True, 20)]
    with torch.no_grad():
        for name, b, shared, facs, s in configs:
            sx = sx_all[s]
            beta = torch.randn(1 if shared else b, s, generator=gen)
            psi = torch.rand(b, model.num_expressions, generator=gen)
            if facs:
                psi = model.expression_vector("mouthSmile_L=0.7, mouthSmile_R=0.7, jawOpen=0.3, "
                                               "cheekSquint_L=0.5, cheekSquint_R=0.5")[None]
            theta = distribute_head_rotation(0.3 * torch.randn(b, 3, generator=gen))
            go = 0.1 * torch.randn(b, 3, generator=gen)
            eta = 0.5 + torch.rand(b, generator=gen)
            tau = 0.005 * torch.randn(b, generator=gen)
            pose = torch.cat([go[:, None], theta], 1).reshape(b, -1)
            betas_sx = torch.cat([beta.expand(b, -1), psi], 1)
            nbytes = bytes_read(model, beta, psi, theta)
            floor = floor_buffer(nbytes, model.expr_shape_basis.shape[1])
            coeffs = torch.randn(b, floor.shape[0], generator=gen)
            sx_floor = floor_buffer(smplx_bytes(sx), model.expr_shape_basis.shape[1])
            sx_coeffs = torch.randn(b, sx_floor.shape[0], generator=gen)
            hack_kw = {"beta": beta, "psi": psi, "theta": theta, "global_orient": go,
                       "eta": eta, "tau": tau}
            fns = {
                "hack": lambda kw=hack_kw: model(**kw),
                "smplx": lambda b_=betas_sx, p_=pose, s_=sx: smplx_lbs(b_, p_, **s_),
                "floor": lambda c_=coeffs, f_=floor: c_ @ f_,
                "smplx_floor": lambda c_=sx_coeffs, f_=sx_floor: c_ @ f_,
            }
            if b == 1:
                fns["hack_one_thread"] = lambda kw=hack_kw: one_thread(model, kw)
            times = interleaved(fns, args.repeats, args.clock)
            s = {k: summary(v) for k, v in times.items()}
            row = {**s, "bytes_read_mb": nbytes / 1e6, "smplx_bytes_read_mb": smplx_bytes(sx) / 1e6,
                   "hack_over_smplx": s["hack"]["median_ms"] / s["smplx"]["median_ms"],
                   "hack_over_floor": s["hack"]["median_ms"] / s["floor"]["median_ms"],
                   "smplx_over_its_floor": (s["smplx"]["median_ms"]
                                            / s["smplx_floor"]["median_ms"])}
            if b == 1:
                row["hack_one_thread_over_smplx"] = (s["hack_one_thread"]["median_ms"]
                                                     / s["smplx"]["median_ms"])
            results["configs"][name] = row
            say(f"{name:22s} hack {s['hack']['median_ms']:8.2f} ms "
                f"[{s['hack']['min_ms']:.2f}..{s['hack']['max_ms']:.2f}]  smplx "
                f"{s['smplx']['median_ms']:8.2f} ms [{s['smplx']['min_ms']:.2f}.."
                f"{s['smplx']['max_ms']:.2f}] ({smplx_bytes(sx) / 1e6:.1f} MB)  floor "
                f"({nbytes / 1e6:.1f} MB) {s['floor']['median_ms']:7.2f} ms  hack/smplx "
                f"{row['hack_over_smplx']:.2f}x  hack/floor {row['hack_over_floor']:.2f}x  "
                f"smplx/its floor {row['smplx_over_its_floor']:.2f}x"
                + (f"  helper off: {s['hack_one_thread']['median_ms']:.2f} ms "
                   f"({row['hack_one_thread_over_smplx']:.2f}x smplx)" if b == 1 else ""))
        beta1 = torch.randn(1, model.num_shape, generator=gen)
        pers = model.personalize(beta1)
        psi = torch.rand(1, model.num_expressions, generator=gen)
        theta = distribute_head_rotation(0.3 * torch.randn(1, 3, generator=gen))
        times = interleaved({"general": lambda: model(beta=beta1, psi=psi, theta=theta),
                             "personalised": lambda: pers(psi=psi, theta=theta)}, args.repeats,
                            args.clock)
        s = {k: summary(v) for k, v in times.items()}
        s["speed_up"] = s["general"]["median_ms"] / s["personalised"]["median_ms"]
        results["configs"]["B=1 personalised vs general"] = s
        say(f"fixed identity, B=1: general {s['general']['median_ms']:.2f} ms, personalised "
            f"{s['personalised']['median_ms']:.2f} ms, speed-up {s['speed_up']:.2f}x")
    results["load_average_1min_after"] = os.getloadavg()[0]
    results["printed"] = PRINTED
    say(f"1-min load average after: {results['load_average_1min_after']:.1f}")
    beside = f", beside {args.hogs} CPU-bound process(es)" if args.hogs else ""
    results["title"] = (f"Geometry forward against smplx's lbs ({results['threads']} torch "
                        f"thread(s), {args.clock} clock{beside})")
    print(f"wrote {write_result(args.out, results)}")


if __name__ == "__main__":
    main()
