"""Procedural subjects through A(alpha): a subject's skin at a few per cent of the cost.

:func:`appearance.generator.generate_subject` evaluates its noise fields, spots and
wrinkles on every texel: about 1 s a subject at H = 256, twice a dataset sample's render.
:class:`SubjectProjector` generates the subject at :data:`PROBE_HEIGHT` instead (1/16 of
the texels at 64, ~40 ms), projects its maps onto the appearance model downsampled to that
height (least squares over every component, one (K, 7N') product with a precomputed
pseudo-inverse), and evaluates A(alpha) at the height asked for: one (1, K) x (K, 7N)
product and a gather (~15 ms at 256).

What it keeps: the subject's skin tone and its regional colour (lips, cheeks, brows,
stubble, scalp), specular and roughness layout, the large-scale mottling: the population's
distribution of skin tones (``bench/bench_dataset.py`` prints the generator's and this
path's ITA, L* and b* percentiles over the same subjects; docs/datasets.md). What it loses:
detail finer than the model's components hold (single freckles, moles, wrinkle lines):
the maps are the model's reconstruction of the subject, as ``hack-render fit`` sees skin.

The subject is a pure function of its seed; alpha is computed in float64 and rounded to
float32, so it is the same bits whatever the thread count (serial or Ray workers).
"""

from __future__ import annotations

import inspect

import numpy as np
import torch

from appearance.cache import cached_arrays, file_key, source_key
from appearance.generator import generate_subject
from appearance.model import DEFAULT_MODEL, AppearanceMaps, AppearanceModel, normals_to_slopes
from appearance.population import Calibration
from hack_render.errors import HackError

#: Atlas height of the generated probe: at 64 a subject's forehead ITA is within ~3
#: degrees of the full-resolution subject's projection (at 32, up to 7).
PROBE_HEIGHT = 64


def supports_height(height: int, model_height: int) -> bool:
    """Whether maps of atlas ``height`` come from a model of ``model_height``: its own
    height divided by a power of two (the model's mip levels)."""
    h, m = int(height), int(model_height)
    return 0 < h <= m and m % h == 0 and (m // h) & (m // h - 1) == 0


def model_height(path=None) -> int:
    """The atlas height of a model file (default: the shipped one), read alone."""
    with np.load(path or DEFAULT_MODEL, allow_pickle=False) as z:
        return int(z["height"])


class SubjectProjector:
    """Procedural subjects (by seed) as appearance coefficients and skin maps.

    Args:
        model: the appearance model (default: the shipped procedural one).
        probe_height: atlas height of the generated probe (``model.height`` / 2^k).
        calibration: the generator's calibration (default: the shipped one).
    """

    def __init__(self, model: AppearanceModel | None = None, probe_height: int = PROBE_HEIGHT,
                 calibration: Calibration | None = None):
        self.model = model if model is not None else AppearanceModel.load()
        self.calibration = calibration
        self.probe_height = int(probe_height)

        def operators() -> tuple[dict[str, np.ndarray], dict]:
            probe = self.model.downsampled(self.probe_height)
            basis = probe.basis.detach().cpu().double()  # (K, 7N'), scaled: alpha ~ N(0, I)
            return ({"pinv": torch.linalg.solve(basis @ basis.T, basis).numpy(),
                     "mean": probe.mean.detach().cpu().double().numpy(),
                     "mask": probe.mask_np}, {})

        if model is None and DEFAULT_MODEL.is_file():
            # the shipped model's operators are kept on disk (~0.3 s to make; same bits)
            code = source_key(__file__, inspect.getfile(AppearanceModel))
            ops = cached_arrays("projector", [file_key(DEFAULT_MODEL), self.probe_height, code],
                                operators)[0]
        else:
            ops = operators()[0]
        #: (K, 7N') least-squares operator: alpha = pinv @ (x - mean)
        self.pinv, self.mean, self.mask = ops["pinv"], ops["mean"], ops["mask"]
        self._maps_models: dict[int, AppearanceModel] = {self.model.height: self.model}

    def supports(self, height: int) -> bool:
        """Whether maps of this atlas height come from the model (:func:`supports_height`)."""
        return supports_height(height, self.model.height)

    def alpha(self, seed: int) -> torch.Tensor:
        """(1, K) float32 coefficients of subject ``seed`` (every component)."""
        ts = generate_subject(int(seed), self.probe_height, self.calibration)
        x = np.concatenate([ts.diffuse, ts.specular, ts.roughness,
                            normals_to_slopes(ts.normal)], -1)[self.mask]
        a = self.pinv @ (x.astype(np.float64).ravel() - self.mean)
        return torch.from_numpy(a.astype(np.float32))[None]

    def maps(self, seed: int, height: int | None = None) -> AppearanceMaps:
        """Skin maps of subject ``seed`` at atlas ``height`` (default: the model's)."""
        h = self.model.height if height is None else int(height)
        if not self.supports(h):
            raise HackError(f"appearance height: expected the model's {self.model.height} "
                            f"divided by a power of two, found {h}. Use the generator "
                            "(appearance.maps: generated) for other sizes.")
        if h not in self._maps_models:
            self._maps_models[h] = self.model.downsampled(h)
        with torch.no_grad():
            return self._maps_models[h].maps(self.alpha(seed))
