"""What a built :class:`~hack_render.render.scene.HeadScene` gives: its image (passes of
samples averaged, the skin's subsurface scattering, the denoiser, the backdrop behind the
subject) and its pixel-centre G-buffer, label passes and point visibility
(``render/aov.py``'s). :class:`SceneImages` holds these methods; ``scene.py`` builds the
scene and changes it through its parameters."""

from __future__ import annotations

import warnings

import numpy as np
from tqdm import tqdm

from hack_render.errors import HackError
from hack_render.render import denoise as dn
from hack_render.render.aov import (
    environment_backdrop,
    gbuffer,
    label_pass,
    point_visibility,
    region_hits,
)
from hack_render.render.engine import release_parked
from hack_render.render.footprint import denoise_features
from hack_render.render.parts import REGIONS
from hack_render.render.settings import sampler_spp
from hack_render.render.sss import render_scattered


def composite(image: np.ndarray, backdrop: np.ndarray | None) -> np.ndarray:
    """Premultiplied linear RGBA (H, W, 4) over a linear RGB backdrop (H, W, 3) or None:
    RGB + (1 - alpha) backdrop; alpha is kept (the subject's coverage)."""
    if backdrop is None:
        return image
    out = image.copy()
    out[..., :3] += (1.0 - image[..., 3:4]) * backdrop
    return out



def as_points(x) -> np.ndarray:
    """A NumPy or torch array as float64 NumPy (the scene's vertices)."""
    x = x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)
    return x.astype(np.float64)


class SceneImages:
    """The images and queries of a built scene (:class:`~hack_render.render.scene.HeadScene`
    extends it: its ``scene``, ``settings``, ``skin_bsdf``, ``see_through_cards`` and
    cached ``_backdrop`` are what these read)."""

    def render(self, seed: int | None = None, progress: bool = False,
               backdrop=True, denoise: bool = False, sss: bool = False) -> np.ndarray:
        """Render the image: (H, W, 4) float32 linear Rec.709 RGB + alpha (coverage).

        Samples are split into equal passes of at most ``SAMPLES_PER_PASS`` samples with
        seeds derived from ``seed`` (default: the settings' seed), then averaged.

        Camera rays never see an emitter (the path integrator's ``hide_emitters``): the
        film holds the subject alone, RGB premultiplied by the alpha. ``backdrop`` says
        what fills the rest: True, the rig's environment as seen along each pixel's
        centre ray (:meth:`backdrop`); False, nothing (premultiplied RGBA, for
        compositing); or an (H, W, 3) linear image composited behind the subject.
        ``denoise``: run Intel Open Image Denoise on the subject before compositing
        (:meth:`denoise`; raises ``denoise.DenoiserUnavailable`` without pyoidn).
        ``sss``: subsurface scattering in the skin (:mod:`hack_render.render.sss`: the
        skin's diffuse light rendered apart, in the same pass with ``hack_path``, in a
        second with the other integrators, then diffused by the skin profile); JIT
        variants only (the scalar variant's stand-in skin material renders without it,
        with a warning).
        """
        release_parked()
        base = self.settings.seed if seed is None else int(seed)
        if sss and self.skin_bsdf is None:
            warnings.warn("sss: subsurface scattering needs the hack_skin material of a JIT "
                          "variant (llvm_ad_rgb or cuda_ad_rgb); rendering without it.",
                          stacklevel=2)
            sss = False
        if sss:
            img = render_scattered(self, base, progress)
        else:
            img = self.render_passes(base, progress)
        if denoise:
            img = self.denoise(img)
        return composite(img, self._backdrop_of(backdrop))

    def render_passes(self, base: int, progress: bool, desc: str = "render passes",
                       spp: int | None = None, integrator=None):
        """The premultiplied film averaged over the settings' passes (see :meth:`render`);
        ``spp``: samples per pixel of each pass instead of the settings' (rounded as the
        sampler takes them); ``integrator``: a Mitsuba integrator instead of the scene's
        (its AOVs follow the RGBA channels)."""
        import mitsuba as mi

        n, _ = self.settings.passes
        kw = {} if spp is None else {"spp": sampler_spp(self.settings.mitsuba_sampler,
                                                        max(1, int(spp)))}
        if integrator is not None:
            kw["integrator"] = integrator
        acc = None
        steps = range(n)
        if progress and n > 1:
            steps = tqdm(steps, desc=desc, unit="pass")
        for i in steps:
            img = np.asarray(mi.render(self.scene, seed=(base * 7919 + i) % (2 ** 31), **kw))
            acc = img if acc is None else acc + img
        return (acc / n).astype(np.float32)

    def denoise(self, image: np.ndarray, fallback: bool = False, k: int = 4) -> np.ndarray:
        """A premultiplied render (H, W, 4) of this scene's current state (camera, mesh),
        denoised by OIDN with albedo and normal from :func:`footprint.denoise_features`
        (through the lash cards, as the film sees them); alpha kept. ``fallback``: a missing or failing denoiser returns the image unchanged
        with a warning instead of raising (see ``hack_render.render.denoise``)."""
        albedo, normal = denoise_features(self, k, self.see_through_cards)
        out = image.copy()
        den = dn.denoise(image[..., :3], albedo, normal, fallback=fallback)
        # premultiplied: no coverage, no colour (OIDN leaves ~1e-6 residues there)
        out[..., :3] = np.where(image[..., 3:4] > 0, den, 0.0)
        return out

    def composite(self, image: np.ndarray, backdrop=True) -> np.ndarray:
        """A premultiplied render (``render(backdrop=False)``) over ``backdrop`` (see
        :meth:`render`)."""
        return composite(image, self._backdrop_of(backdrop))

    def _backdrop_of(self, backdrop) -> np.ndarray | None:
        if backdrop is True:
            return self.backdrop()
        if backdrop is False or backdrop is None:
            return None
        bg = np.asarray(backdrop, dtype=np.float32)
        shape = (self.settings.height, self.settings.width, 3)
        if bg.shape != shape or not np.all(np.isfinite(bg)):
            raise HackError(f"backdrop: expected a finite linear RGB image of shape {shape}, "
                            f"found {bg.shape}.")
        return bg

    def backdrop(self) -> np.ndarray:
        """(H, W, 3) float32: the environment's radiance along each pixel-centre camera
        ray (zeros without an environment); what the camera would see behind the
        subject, lights excluded. Cached until the camera or the rig moves."""
        if self._backdrop is None:
            self._backdrop = environment_backdrop(self)
        return self._backdrop

    def aovs(self, see_through=(), hits: bool = False) -> dict[str, np.ndarray]:
        """Pixel-centre G-buffer: see :func:`hack_render.render.aov.gbuffer`."""
        return gbuffer(self, see_through, hits)

    def region_hits(self, offset=(0.5, 0.5), see_through=("eyelashes",)) -> dict:
        """Region ids and model UVs at one sub-pixel point: see :func:`aov.region_hits`."""
        return region_hits(self, offset, see_through)

    def label_pass(self, k: int, region_labels, uv_label_map, uv_regions=(),
                   see_through=("eyelashes",), num_labels: int | None = None,
                   see_through_opacity: float | None = None) -> dict:
        """Label coverage of k x k sub-pixel rays and the pixel-centre G-buffer in one
        batch: see :func:`aov.label_pass`."""
        return label_pass(self, k, region_labels, uv_label_map, uv_regions, see_through,
                          num_labels, see_through_opacity)

    def visibility(self, points, tolerance: float = 2e-3, see_through=("eyelashes",)):
        """Line-of-sight visibility of world points: see :func:`aov.point_visibility`."""
        return point_visibility(self, points, tolerance, see_through)

    @property
    def region_names(self) -> tuple[str, ...]:
        return REGIONS
