"""Lighting for the photometric stage: order-2 spherical harmonics or free env texels,
both turned into a lat-long environment map (h, 2h, 3) in torch for the renderer."""

from __future__ import annotations

import numpy as np
import torch


def sh_basis(dirs: torch.Tensor) -> torch.Tensor:
    """Real SH basis up to order 2 at unit directions (..., 3) -> (..., 9)."""
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    return torch.stack([
        0.282095 * torch.ones_like(x),
        0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0),
        1.092548 * x * z, 0.546274 * (x * x - y * y)], dim=-1)


class Lighting(torch.nn.Module):
    """A learnable environment: ``mode`` "sh" (9 x 3 coefficients, world frame) or "env"
    (log-radiance texels at ``height`` x 2 ``height``). :meth:`env_map` -> (h, 2h, 3) >= 0."""

    def __init__(self, mode: str = "sh", height: int = 16):
        super().__init__()
        from scenes.lights import latlong_directions

        self.mode, self.height = mode, int(height)
        dirs = torch.as_tensor(latlong_directions(self.height), dtype=torch.float32)
        self.register_buffer("basis", sh_basis(dirs))  # (h, 2h, 9)
        if mode == "sh":
            c = torch.zeros(9, 3)
            c[0] = 1.0 / 0.282095  # unit radiance
            self.coeffs = torch.nn.Parameter(c)
        else:
            self.log_texels = torch.nn.Parameter(torch.zeros(self.height, 2 * self.height, 3))

    def env_map(self) -> torch.Tensor:
        if self.mode == "sh":
            env = torch.einsum("hwk,kc->hwc", self.basis, self.coeffs)
            # a soft floor keeps radiance non-negative without killing gradients
            return torch.nn.functional.softplus(env * 20.0) / 20.0
        return torch.exp(self.log_texels)

    def scale_(self, rgb: np.ndarray) -> None:
        """Multiply the radiance by per-channel factors (used to match the photo's exposure)."""
        with torch.no_grad():
            s = torch.as_tensor(np.asarray(rgb, np.float32))
            if self.mode == "sh":
                self.coeffs.mul_(s[None])
            else:
                self.log_texels.add_(torch.log(s)[None, None])

    def smoothness(self) -> torch.Tensor:
        """Regulariser: higher SH bands / texel differences (keeps lighting low-frequency)."""
        if self.mode == "sh":
            return (self.coeffs[4:] ** 2).sum() / (self.coeffs[0] ** 2).sum().clamp_min(1e-6)
        t = self.log_texels
        return ((t[1:] - t[:-1]) ** 2).mean() + ((t[:, 1:] - t[:, :-1]) ** 2).mean()
