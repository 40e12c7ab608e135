"""Lighting for the photometric stage, turned into a lat-long environment map (h, 2h, 3)
in torch for the renderer:

- ``"sh"``: order-2 spherical harmonics (9 x 3 coefficients), low frequency only;
- ``"env"``: free log-radiance texels;
- ``"sg"``: the order-2 SH plus ``lobes`` spherical Gaussians
  ``a exp(lambda (mu . w - 1))`` (direction mu, sharpness lambda, RGB amplitude a), for a
  dominant light (a window, a soft box, the sun) whose shadows the SH cannot hold. The
  lobes start from :func:`candidate_directions`, the best of which
  ``photometric.init_lobes`` picks by the photo (rendering is linear in the light).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from scenes.lights import latlong_directions


def sh_basis(dirs: torch.Tensor) -> torch.Tensor:
    """Real SH basis up to order 2 at unit directions (..., 3) -> (..., 9)."""
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    return torch.stack([
        0.282095 * torch.ones_like(x),
        0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0),
        1.092548 * x * z, 0.546274 * (x * x - y * y)], dim=-1)


def candidate_directions(n: int = 32) -> np.ndarray:
    """(n, 3) unit directions spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    y = 1.0 - 2.0 * i / n
    r = np.sqrt(np.clip(1.0 - y * y, 0.0, 1.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


def max_sharpness(height: int) -> float:
    """The sharpest lobe a map of ``height`` rows resolves: angular std 1/sqrt(lambda)
    no smaller than one texel (pi / height)."""
    return (height / math.pi) ** 2


class Lighting(torch.nn.Module):
    """A learnable environment in the world frame; ``mode`` "sh", "env" or "sg" (module
    docstring). :meth:`env_map` -> (h, 2h, 3) >= 0."""

    def __init__(self, mode: str = "sh", height: int = 16, lobes: int = 1):
        super().__init__()

        self.mode, self.height = mode, int(height)
        dirs = torch.as_tensor(latlong_directions(self.height), dtype=torch.float32)
        self.register_buffer("dirs", dirs)  # (h, 2h, 3)
        self.register_buffer("basis", sh_basis(dirs))  # (h, 2h, 9)
        if mode in ("sh", "sg"):
            c = torch.zeros(9, 3)
            c[0] = 1.0 / 0.282095  # unit radiance
            self.coeffs = torch.nn.Parameter(c)
        else:
            self.log_texels = torch.nn.Parameter(torch.zeros(self.height, 2 * self.height, 3))
        if mode == "sg":
            k = int(lobes)
            # off until init_lobes (or the optimiser) gives them a direction and radiance
            self.lobe_dir = torch.nn.Parameter(torch.tensor([[0.0, 0.0, 1.0]]).repeat(k, 1))
            self.lobe_log_sharpness = torch.nn.Parameter(torch.full((k,), math.log(10.0)))
            self.lobe_log_amplitude = torch.nn.Parameter(torch.full((k, 3), -12.0))

    def lobe_map(self, direction: torch.Tensor, sharpness: torch.Tensor) -> torch.Tensor:
        """(h, 2h) unit-amplitude spherical Gaussian around ``direction`` (3,)."""
        mu = direction / direction.norm().clamp_min(1e-8)
        return torch.exp(sharpness * ((self.dirs @ mu) - 1.0))

    def sharpness(self) -> torch.Tensor:
        """(lobes,) lobe sharpness, at most :func:`max_sharpness` of the map."""
        return self.lobe_log_sharpness.exp().clamp(0.5, max_sharpness(self.height))

    def env_map(self) -> torch.Tensor:
        if self.mode == "env":
            return torch.exp(self.log_texels)
        env = torch.einsum("hwk,kc->hwc", self.basis, self.coeffs)
        # a soft floor keeps radiance non-negative without killing gradients
        env = torch.nn.functional.softplus(env * 20.0) / 20.0
        if self.mode == "sg":
            lam = self.sharpness()
            for j in range(self.lobe_dir.shape[0]):
                env = env + (self.lobe_map(self.lobe_dir[j], lam[j])[..., None]
                             * self.lobe_log_amplitude[j].exp())
        return env

    def scale_(self, rgb: np.ndarray) -> None:
        """Multiply the radiance by per-channel factors (used to match the photo's exposure)."""
        with torch.no_grad():
            s = torch.as_tensor(np.asarray(rgb, np.float32))
            if self.mode == "env":
                self.log_texels.add_(torch.log(s)[None, None])
                return
            self.coeffs.mul_(s[None])
            if self.mode == "sg":
                self.lobe_log_amplitude.add_(torch.log(s)[None])

    def colour_cast(self, gain: torch.Tensor | None = None,
                    reach: torch.Tensor | None = None) -> torch.Tensor:
        """The light's colour cast (a scalar, 0 for grey light): the squared
        log-chromaticity of each direction's radiance (its log per channel less the mean of
        the three logs), summed over the channels and averaged over the directions weighted
        by their share of the light (solid angle times radiance, held fixed; times
        ``reach`` (h, 2h), how much of each direction reaches the skin, e.g. the mean
        clamped cosine over its normals), so no coloured light hides in directions that
        carry little. A uniform tint of log-chromaticity c gives |c|^2. ``gain`` (3,): the
        cast of the radiance times these per-channel factors."""
        env = self.env_map()
        if gain is not None:
            env = env * gain
        log = torch.log(env.clamp_min(1e-8))
        cast = ((log - log.mean(-1, keepdim=True)) ** 2).sum(-1)
        w = torch.sqrt((1.0 - self.dirs[..., 1] ** 2).clamp_min(0.0)) * env.detach().mean(-1)
        if reach is not None:
            w = w * reach
        return (w * cast).sum() / w.sum().clamp_min(1e-12)

    def smoothness(self) -> torch.Tensor:
        """Regulariser: higher SH bands / texel differences (keeps lighting low-frequency;
        the lobes are left free: they are the high frequencies)."""
        if self.mode in ("sh", "sg"):
            return (self.coeffs[4:] ** 2).sum() / (self.coeffs[0] ** 2).sum().clamp_min(1e-6)
        t = self.log_texels
        return ((t[1:] - t[:-1]) ** 2).mean() + ((t[:, 1:] - t[:, :-1]) ** 2).mean()

    def summary(self) -> dict:
        """The lobes (direction, sharpness, RGB amplitude) as plain lists, for the outputs."""
        if self.mode != "sg":
            return {}
        d = self.lobe_dir.detach()
        d = d / d.norm(dim=1, keepdim=True).clamp_min(1e-8)
        return {"lobe_direction": d.tolist(), "lobe_sharpness": self.sharpness().detach().tolist(),
                "lobe_rgb": self.lobe_log_amplitude.detach().exp().tolist()}
