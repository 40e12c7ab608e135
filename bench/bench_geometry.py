"""Geometry forward cost against a physical floor, measured in one run (issue 2, Sec. 6).

Floor: one matrix product that reads the same blendshape bytes once: (B, K) @ (K, 3N) over a
contiguous float32 buffer as large as every basis the general forward reads (the shape,
expression and pose blendshapes, and, when the model carries them, the personalised
expression and pose PCA components and the larynx maps). Reports forward / floor at B = 1
and B = 64, and the speed-up of the personalised forward over the general one for a fixed
identity.

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


def floor_basis(model) -> torch.Tensor:
    """A (K, 3N) float32 buffer with as many bytes as every basis the general forward reads."""
    parts = [model.blend_basis.flatten()]
    for pb in (model.expr_personal, model.pose_personal):
        if pb is not None:
            parts += [pb.components.flatten(), pb.mean.flatten()]
    if model.has_larynx:
        parts.append(model.larynx_maps.flatten())
    flat = torch.cat(parts)
    width = model.blend_basis.shape[1]
    rows = -(-flat.numel() // width)
    return torch.nn.functional.pad(flat, (0, rows * width - flat.numel())).view(rows, width).contiguous()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=30)
    args = ap.parse_args()
    model = load_default_model()
    basis = floor_basis(model)
    gen = torch.Generator().manual_seed(0)
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, bases read by the forward: "
          f"{basis.numel() * 4 / 1e6:.1f} MB float32 (blend basis {tuple(model.blend_basis.shape)}"
          f"{', personalised PCA, larynx maps' if basis.shape[0] > model.blend_basis.shape[0] else ''})")
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
