"""Geometry forward cost against a physical floor, measured in one run (issue 2, Sec. 6).

Floor: one matrix product that reads the same blendshape bytes once ((1, K) @ (K, 3N) over
the model's contiguous float32 basis). Reports forward / floor at B = 1 and B = 64, and the
speed-up of the personalised forward over the general one for a fixed identity.

    python bench/bench_geometry.py [--repeats 30]
"""

from __future__ import annotations

import argparse
import time

import torch

from hack_render.geometry import distribute_head_rotation, load_default_model


def best_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    model = load_default_model()
    basis = model.blend_basis
    gen = torch.Generator().manual_seed(0)
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, basis {tuple(basis.shape)} "
          f"float32 = {basis.numel() * 4 / 1e6:.1f} MB")
    rows = []
    with torch.no_grad():
        for b in (1, 64):
            beta = torch.randn(b, model.num_shape, generator=gen)
            psi = torch.rand(b, model.num_expressions, generator=gen)
            theta = distribute_head_rotation(0.3 * torch.randn(b, 3, generator=gen))
            coeffs = torch.randn(b, basis.shape[0], generator=gen)
            t_floor = best_time(lambda c=coeffs: c @ basis, args.repeats)
            t_fwd = best_time(lambda b_=beta, p_=psi, t_=theta: model(beta=b_, psi=p_, theta=t_),
                              args.repeats)
            rows.append((b, t_fwd, t_floor))
            print(f"B={b:3d}: forward {t_fwd * 1e3:8.2f} ms, matmul floor {t_floor * 1e3:8.2f} ms, "
                  f"ratio {t_fwd / t_floor:5.2f}x (target at B=1: <= 2.0x)")
        beta1 = torch.randn(1, model.num_shape, generator=gen)
        pers = model.personalize(beta1)
        psi = torch.rand(1, model.num_expressions, generator=gen)
        theta = distribute_head_rotation(0.3 * torch.randn(1, 3, generator=gen))
        t_gen = best_time(lambda: model(beta=beta1, psi=psi, theta=theta), args.repeats)
        t_per = best_time(lambda: pers(psi=psi, theta=theta), args.repeats)
        print(f"fixed identity, B=1: general {t_gen * 1e3:.2f} ms, personalised {t_per * 1e3:.2f} ms, "
              f"speed-up {t_gen / t_per:.2f}x")


if __name__ == "__main__":
    main()
