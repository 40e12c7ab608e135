"""The torch <-> Dr.Jit bridge: differentiable renders of a :class:`HeadScene` from torch.

:class:`DiffRenderer` wraps a built :class:`~hack_render.render.scene.HeadScene` and renders
it from torch tensors with ``dr.wrap(source="torch", target="drjit")``, so a torch loss on
the image back-propagates (through Dr.Jit's reverse-mode AD) into:

- ``vertices`` (N, 3) metres: every render part's positions, and its normals (computed
  here in torch from the positions, so shading normals carry gradients too);
- skin maps ``albedo`` (H, 2H, 3), ``specular`` / ``roughness`` (H, 2H, 1), ``normal``
  (H, 2H, 3) (the ``hack_skin`` textures);
- ``light_rotation_deg`` (1,): rotation of the whole rig (environment and area lights)
  about +Y, degrees;
- ``focal_px`` (1,): the focal length in pixels (through the sensor's field of view);
- ``env`` (h, 2h, 3): the texels of the environment map (its rig must have one of this
  size: build the scene with ``LightRig(env_map=...)``).

Inputs that are None keep the scene's current value. Visibility: the default integrator
is Mitsuba's ``prb`` (max depth 2: direct lighting from the environment and area lights,
with shadows), which differentiates shading but not silhouettes or shadow boundaries;
``direct_projective`` also differentiates silhouettes (about 50x slower on a CPU, see
docs/fit.md). The image is linear RGBA (H, W, 4); alpha is coverage.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.render.emitters import area_light_transform
from hack_render.render.engine import is_jit, release_parked, release_when_safe
from hack_render.render.parts import cap_apex

INTEGRATORS = ("prb", "direct_projective", "prb_projective")


def vertex_normals_torch(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals, differentiable. vertices (N, 3), faces (F, 3) long.

    One ``index_select`` per corner and one ``index_add_`` of the face normals per corner
    (backward: scatter-adds and gathers of (F, 3) rows). Gathering all corners at once as
    (F, 3, 3) was ~1.5x slower forward + backward on the CPU for the 26k-vertex head (its
    backward zero-fills and sums (F, 3, 3) buffers per slice); fancy indexing's backward,
    an accumulating ``index_put_`` that sorts the indices first, slower still."""
    f0, f1, f2 = faces[:, 0], faces[:, 1], faces[:, 2]
    a = vertices.index_select(0, f0)
    fn = torch.linalg.cross(vertices.index_select(0, f1) - a, vertices.index_select(0, f2) - a)
    n = torch.zeros_like(vertices).index_add_(0, f0, fn).index_add_(0, f1, fn).index_add_(0, f2, fn)
    length = torch.linalg.vector_norm(n, dim=1, keepdim=True)
    # isolated vertices (zero normal) stay zero instead of dividing by zero
    return n / torch.where(length > 0, length, torch.ones_like(length))


def fov_from_focal(focal_px: torch.Tensor, width: int) -> torch.Tensor:
    """Horizontal field of view (degrees) of a focal length in pixels (tensor in, tensor out)."""
    return torch.rad2deg(2.0 * torch.atan(0.5 * width / focal_px))


class DiffRenderer:
    """Differentiable renders of a head scene from torch tensors (see the module docstring).

    Args:
        head: a built :class:`HeadScene` in a JIT variant (``llvm_ad_rgb``/``cuda_ad_rgb``).
        integrator: one of :data:`INTEGRATORS`.
        max_depth: path depth of the integrator (2 = direct lighting only).
        spp: samples per pixel of the primal and of the adjoint pass (default: the scene's).
    """

    def __init__(self, head, integrator: str = "prb", max_depth: int = 2, spp: int | None = None):
        import mitsuba as mi

        if not is_jit(head.variant):
            raise HackError(f"differentiable rendering: expected a JIT variant (llvm_ad_rgb or "
                            f"cuda_ad_rgb), found {head.variant!r}. Install LLVM 16+ "
                            "(`apt-get install libllvm19`) or unset HACK_RENDER_VARIANT.")
        if integrator not in INTEGRATORS:
            raise HackError(f"integrator: expected one of {', '.join(INTEGRATORS)}, found "
                            f"{integrator!r}.")
        self.head = head
        self.integrator_name = integrator
        d = {"type": integrator, "max_depth": int(max_depth)}
        if integrator == "direct_projective":
            d = {"type": integrator}
        self.integrator = mi.load_dict(d)
        release_when_safe(self, self.integrator)  # see engine.release_when_safe
        self.spp = int(spp or head.settings.spp)
        self.width, self.height = head.settings.width, head.settings.height
        self._faces = torch.as_tensor(head.topology.faces, dtype=torch.long)
        # every part's model-vertex indices back to back: one gather of positions and one
        # of normals for all parts, then views per part (one scatter each backward)
        self._part_names = [p.name for p in head.parts]
        self._part_sizes = [len(p.gather) for p in head.parts]
        self._gather = torch.as_tensor(np.concatenate([p.gather for p in head.parts]),
                                       dtype=torch.long)
        self._light_base = self._light_bases()
        self._fn = self._make_render_fn()
        self._last: dict[str, torch.Tensor] = {}  # constant inputs already in the scene

    # --- scene structure ---------------------------------------------------------------
    def _light_bases(self) -> dict[str, np.ndarray]:
        """Unrotated ``to_world`` (4, 4) of each area light of the rig."""
        return {f"light_{i}": area_light_transform(light, 0.0)
                for i, light in enumerate(self.head.lights.area)
                if f"light_{i}.to_world" in self.head.params}

    @property
    def skin_key(self) -> str:
        return self.head._skin_key

    @property
    def env_shape(self) -> tuple[int, int, int] | None:
        """(h, 2h, 3) of the scene's environment map texels, or None without one."""
        p = self.head.params
        if "environment.data" not in p:
            return None
        h, w, c = p["environment.data"].shape
        return (h, w - 2, c)

    def _make_render_fn(self):
        import drjit as dr
        import mitsuba as mi

        head, params = self.head, self.head.params
        skin = self.skin_key
        light_base = {k: mi.Matrix4f(v.tolist()) for k, v in self._light_base.items()}
        has_env_rot = "environment.to_world" in params

        @dr.wrap(source="torch", target="drjit")
        def render(inputs, seed, seed_grad, spp):
            for name, x in inputs.items():
                if name.startswith("pos:"):
                    params[f"{name[4:]}.vertex_positions"] = x.array
                elif name.startswith("nrm:"):
                    params[f"{name[4:]}.vertex_normals"] = x.array
                elif name.startswith("map:"):
                    params[f"{skin}.{name[4:]}.data"] = x
                elif name == "env":
                    params["environment.data"] = x
                elif name == "fov":
                    params["sensor.x_fov"] = x.array
                elif name == "rot":
                    r = dr.deg2rad(x.array)
                    c, s = dr.cos(r), dr.sin(r)
                    m = mi.Matrix4f(c, 0, s, 0, 0, 1, 0, 0, -s, 0, c, 0, 0, 0, 0, 1)
                    if has_env_rot:
                        params["environment.to_world"] = mi.Transform4f(m)
                    for key, base in light_base.items():
                        params[f"{key}.to_world"] = mi.Transform4f(m @ base)
            params.update()
            return mi.render(head.scene, params, integrator=self.integrator, seed=seed,
                             seed_grad=seed_grad, spp=spp)

        return render

    # --- the differentiable render -----------------------------------------------------
    def inputs(self, vertices=None, albedo=None, specular=None, roughness=None, normal=None,
               light_rotation_deg=None, focal_px=None, env=None) -> dict[str, torch.Tensor]:
        """Translate model-level tensors into the flat per-parameter tensors Mitsuba wants."""
        out: dict[str, torch.Tensor] = {}
        if vertices is not None:
            v = vertices.reshape(-1, 3)
            if v.shape[0] != self.head.topology.num_vertices:
                raise HackError(f"vertices: expected ({self.head.topology.num_vertices}, 3), "
                                f"found {tuple(vertices.shape)}.")
            v = v.float()
            n = vertex_normals_torch(v, self._faces)
            pos = v.index_select(0, self._gather).split(self._part_sizes)
            nrm = n.index_select(0, self._gather).split(self._part_sizes)
            for part, p, q in zip(self.head.parts, pos, nrm):
                if part.apex:  # the bust cap's apex, from its gathered loop
                    p = torch.cat([p, cap_apex(p, part.apex)[None]])
                out[f"pos:{part.name}"] = p.reshape(-1)
                if not part.flat:  # flat-shaded parts (the bust cap) have no normals
                    out[f"nrm:{part.name}"] = q.reshape(-1)
        for key, x in (("albedo", albedo), ("specular", specular), ("roughness", roughness),
                       ("normalmap", normal)):
            if x is None:
                continue
            full = f"{self.skin_key}.{key}.data"
            if full not in self.head.params:
                raise HackError(f"skin map {key!r}: this scene's skin material has none (build "
                                "the HeadScene with maps that include it).")
            want = tuple(self.head.params[full].shape)
            if tuple(x.shape) != want:
                raise HackError(f"skin map {key!r}: expected shape {want} (the scene's), found "
                                f"{tuple(x.shape)}. Keep the map size fixed while fitting.")
            out[f"map:{key}"] = x.float().contiguous()
        if env is not None:
            shape = self.env_shape
            if shape is None or tuple(env.shape) != shape:
                raise HackError(f"env: expected texels of shape {shape} (the rig's environment "
                                f"map), found {tuple(env.shape)}.")
            e = env.float()
            out["env"] = torch.cat([e[:, -1:], e, e[:, :1]], dim=1).contiguous()
        if focal_px is not None:
            out["fov"] = fov_from_focal(focal_px.reshape(1).float(), self.width)
        if light_rotation_deg is not None:
            out["rot"] = light_rotation_deg.reshape(1).float()
        return out

    def render(self, seed: int = 0, spp: int | None = None, seed_grad: int | None = None,
               **tensors) -> torch.Tensor:
        """Render (H, W, 4) linear RGBA as a torch tensor; gradients flow to ``tensors``.

        Keyword arguments: see :meth:`inputs` (vertices, albedo, specular, roughness,
        normal, light_rotation_deg, focal_px, env). ``seed`` picks the primal sample
        pattern; ``seed_grad`` the adjoint pass's (default: derived from ``seed``; Mitsuba
        requires it to differ from ``seed`` so that loss gradients stay unbiased).
        """
        release_parked()
        inputs = self._drop_unchanged(self.inputs(**tensors))
        seed = int(seed) % (2 ** 31)
        sg = (seed * 65599 + 1) % (2 ** 31) if seed_grad is None else int(seed_grad) % (2 ** 31)
        return self._fn(inputs, seed, sg, int(spp or self.spp))

    def _drop_unchanged(self, inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Leave out inputs that need no gradient and equal what the scene already holds.

        Writing a parameter makes Mitsuba refresh its owner (new vertex positions rebuild
        the ray-tracing acceleration structure, about as long as the render itself at
        128 px), so geometry that is frozen in a stage (texel refinement, or photometric
        fits without geometry refinement) is uploaded once instead of every iteration.
        """
        out = {}
        for name, x in inputs.items():
            if x.requires_grad:
                self._last.pop(name, None)
                out[name] = x
                continue
            prev = self._last.get(name)
            if prev is not None and prev.shape == x.shape and torch.equal(prev, x):
                continue
            self._last[name] = x.detach().clone()
            out[name] = x
        return out

    def bare_iteration(self, target: np.ndarray, seed: int, write: bool = True) -> float:
        """One pure-Mitsuba iteration of this scene, the reference for overhead benchmarks.

        With ``write`` the differentiable parameters the bridge feeds (every part's vertex
        positions, the skin maps, the environment texels) are written back first, as a
        Mitsuba optimiser step does (``params.update(opt)``: the geometry is rebuilt,
        Mitsuba recomputes the vertex normals); then ``mi.render`` at this renderer's
        integrator and spp, an L1 loss against ``target`` (H, W, 3), ``dr.backward`` and
        an evaluation of the gradients (which Dr.Jit would otherwise leave unevaluated).
        Without ``write`` the scene is rendered as it is (no geometry rebuild). Returns
        the loss.
        """
        release_parked()
        import drjit as dr
        import mitsuba as mi

        params = self.head.params
        keys = [k for k in params.keys()
                if k.endswith(".vertex_positions") or k == "environment.data"
                or k.startswith(f"{self.skin_key}.") and k.endswith(".data")]
        if write:
            one = dr.opaque(mi.Float, 1.0)  # opaque: x * 1 is a new value, not folded away
            for k in keys:
                x = dr.detach(params[k])
                params[k] = type(x)(x.array * one, x.shape) if isinstance(x, mi.TensorXf) \
                    else x * one
        for k in keys:
            if not dr.grad_enabled(params[k]):
                dr.enable_grad(params[k])  # (a new AD id: the next update() rebuilds)
        params.update()
        img = mi.render(self.head.scene, params, integrator=self.integrator, seed=int(seed),
                        spp=self.spp)
        loss = dr.mean(dr.abs(img[..., :3] - mi.TensorXf(np.asarray(target, np.float32))),
                       axis=None)
        dr.backward(loss)
        grads = [dr.grad(params[k]) for k in keys]
        dr.eval(grads)
        for k in keys:
            dr.clear_grad(params[k])
        return float(loss.array[0])

    def set_focal(self, focal_px: float) -> None:
        """Non-differentiable focal change (pixels), e.g. before rendering a final image."""
        self.head.params["sensor.x_fov"] = math.degrees(2.0 * math.atan(0.5 * self.width / focal_px))
        self.head.params.update()
        self._last.pop("fov", None)
