"""G(beta, psi, theta, eta, tau): the HACK geometry model (paper Eq. 2-3) as a torch module.

    T = T_bar + B_S(beta) + B_E(psi; E_beta) + B_P(theta; P_beta) + L(beta, eta, tau)
    G = LBS(T, J(beta), theta, W)

The module is stateless in its inputs (SMPL-X layer style): every parameter is a call
argument, missing ones are zeros on the buffers' device and dtype, and the batch size comes
from the inputs. ``model.double()`` gives a float64 model for gradient checks.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from hack_render.errors import HackError
from hack_render.geometry import larynx as _larynx
from hack_render.geometry.lbs import (
    chain_parents,
    local_rotations,
    pose_feature,
    rigid_transforms,
    skin,
)
from hack_render.geometry.model_file import load_model_file


@dataclass
class HackOutput:
    """Result of a forward pass (B = batch, N = vertices).

    Attributes:
        vertices: (B, N, 3) posed vertices, metres.
        joints: (B, 8, 3) posed joint positions c7-t1 ... o-c1, metres.
        rest_joints: (B, 8, 3) joint positions in the rest pose, J(beta).
        landmarks: (B, 68, 3) posed Multi-PIE landmark vertices.
        rest_vertices: (B, N, 3) the corrected rest-pose mesh T(beta, psi, theta, eta, tau).
    """

    vertices: torch.Tensor
    joints: torch.Tensor
    rest_joints: torch.Tensor
    landmarks: torch.Tensor
    rest_vertices: torch.Tensor


class _MLP(nn.Module):
    """Three linear layers with ReLU between them (paper Sec. 5.1: 64 units)."""

    def __init__(self, w0, b0, w1, b1, w2, b2):
        super().__init__()
        for i, (w, b) in enumerate(((w0, b0), (w1, b1), (w2, b2))):
            self.register_buffer(f"w{i}", w)
            self.register_buffer(f"b{i}", b)

    def forward(self, beta: torch.Tensor) -> torch.Tensor:
        """beta: (B, S) -> (B, C); betas beyond the first layer's width are ignored."""
        x = beta[:, : self.w0.shape[1]]
        if x.shape[1] < self.w0.shape[1]:
            x = torch.nn.functional.pad(x, (0, self.w0.shape[1] - x.shape[1]))
        x = torch.relu(x @ self.w0.T + self.b0)
        x = torch.relu(x @ self.w1.T + self.b1)
        return x @ self.w2.T + self.b2


def _add_rows(rest: torch.Tensor, index: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """rest (B, N, 3) with delta (B, M, 3) added at vertices ``index`` (M,), out of place.
    One identity (B = 1) adds along dim 0 of the (N, 3) view: index_add on dim 1 takes a
    slower path (forward + backward 1.4-2.3x on the CPU)."""
    if rest.shape[0] == 1:
        n = rest.shape[1]
        return rest.reshape(n, 3).index_add(0, index, delta.reshape(-1, 3)).view(1, n, 3)
    return rest.index_add(1, index, delta)


class _SparseRowsProduct(torch.autograd.Function):
    """coeffs @ (mean + sum_c w_c comps_c); see :func:`sparse_rows_product`."""

    @staticmethod
    def forward(ctx, coeffs, mean, w, comps):
        nz = torch.nonzero(coeffs.ne(0).any(0)).flatten().tolist()
        # read only the rows some coefficient uses: mean's rows, and each used row's
        # components in place (comps[:, d] is a strided (C, K) matrix; no gathered copy)
        out = coeffs[:, nz] @ mean[nz]
        if comps is not None:
            for d in nz:
                out = out + coeffs[:, d:d + 1] * (w @ comps[:, d])
        ctx.save_for_backward(coeffs, mean, w, comps)
        return out

    @staticmethod
    def backward(ctx, g):
        coeffs, mean, w, comps = ctx.saved_tensors
        need_c, need_w = ctx.needs_input_grad[0], ctx.needs_input_grad[2]
        grad_c = g @ mean.T if need_c else None
        grad_w = None
        if comps is not None and (need_c or need_w):
            C, D, K = comps.shape
            G = (comps.reshape(C * D, K) @ g.T).view(C, D, -1)  # the one full read
            if need_c:
                grad_c = grad_c + torch.einsum("bc,cdb->bd", w, G)
            if need_w:
                grad_w = torch.einsum("bd,cdb->bc", coeffs, G)
        return grad_c, None, grad_w, None


def sparse_rows_product(coeffs: torch.Tensor, mean: torch.Tensor, w: torch.Tensor | None = None,
                        comps: torch.Tensor | None = None) -> torch.Tensor:
    """``coeffs @ (mean + sum_c w[:, c] comps[c])`` per batch row, (B, K), exact and
    differentiable in ``coeffs`` (B, D) and ``w`` (B, C) (not in the buffers ``mean``
    (D, K) and ``comps`` (C, D, K)).

    The forward reads only the basis rows d where some ``coeffs[:, d]`` is nonzero: the
    fitted expression weights are clamped to [0, 1] under an L1 prior, so most are exactly
    zero. The backward reads the whole basis once and gets both gradients from that one
    pass (``G = comps @ g``: d/dcoeffs = w G + mean g, d/dw = coeffs G), where autograd
    of the dense expression read the components once forward and once backward."""
    if bool(coeffs.ne(0).all()):  # every row used: plain autograd (as fast, no saved state)
        if comps is None:
            return coeffs @ mean
        C, D, K = comps.shape
        basis = (w @ comps.reshape(C, D * K)).view(w.shape[0], D, K) + mean
        return torch.bmm(coeffs.unsqueeze(1), basis).squeeze(1)
    if comps is None:
        return _SparseRowsProduct.apply(coeffs, mean, None, None)
    return _SparseRowsProduct.apply(coeffs, mean, w, comps)


class _PersonalBasis(nn.Module):
    """Personalised deltas on M vertices: mean + sum_c w_c(beta) components_c (D deltas)."""

    def __init__(self, arrays: dict[str, np.ndarray], prefix: str):
        super().__init__()
        t = lambda k: torch.as_tensor(arrays[f"{prefix}_{k}"])
        self.register_buffer("vertices", t("pca_vertices").long())
        mean, comps = t("pca_mean").float(), t("pca_components").float()
        self.register_buffer("mean", mean.reshape(mean.shape[0], -1))  # (D, 3M)
        self.register_buffer("components", comps.reshape(comps.shape[0], comps.shape[1], -1))  # (C, D, 3M)
        self.mlp = _MLP(*(t(f"mlp_{k}").float() for k in ("w0", "b0", "w1", "b1", "w2", "b2")))

    def apply(self, coeffs: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
        """Personal part of coeffs @ basis. coeffs: (B, D), beta: (B, S) -> (B, M, 3)."""
        out = sparse_rows_product(coeffs, self.mean, self.mlp(beta), self.components)
        return out.reshape(coeffs.shape[0], -1, 3)

    def basis(self, beta: torch.Tensor) -> torch.Tensor:
        """The personal deltas themselves for one identity. beta: (1, S) -> (D, M, 3)."""
        w = self.mlp(beta)[0]
        return (self.mean + torch.einsum("c,cdk->dk", w, self.components)).reshape(self.mean.shape[0], -1, 3)


class HackModel(nn.Module):
    """The HACK geometry model. Build with :meth:`from_file` or :func:`load_default_model`."""

    def __init__(self, arrays: dict[str, np.ndarray], meta: dict[str, Any] | None = None):
        super().__init__()
        self.meta = dict(meta or {})
        f32 = lambda k: torch.as_tensor(np.asarray(arrays[k], dtype=np.float32))
        i64 = lambda k: torch.as_tensor(np.asarray(arrays[k], dtype=np.int64))
        self.register_buffer("template", f32("template_vertices"))
        n = self.template.shape[0]
        self.num_vertices = n
        self.register_buffer("faces", i64("faces"))
        self.register_buffer("uvs", f32("uvs"))
        self.register_buffer("uv_faces", i64("uv_faces"))
        self.register_buffer("face_material", i64("face_material"))
        self.register_buffer("vertex_uv", f32("vertex_uv"))
        self.register_buffer("vertex_group", i64("vertex_group"))
        self.register_buffer("vertex_region", i64("vertex_region"))
        self.register_buffer("landmark_indices", i64("landmark_indices"))
        self.material_names = tuple(str(s) for s in arrays["material_names"])
        self.group_names = tuple(str(s) for s in arrays["group_names"])
        self.region_names = tuple(str(s) for s in arrays["region_names"])
        self.expression_names = tuple(str(s) for s in arrays["expression_names"])
        self.au_names = tuple(str(s) for s in arrays["au_names"])
        self.joint_names = tuple(str(s) for s in arrays["joint_names"])
        self.parents = tuple(int(p) for p in arrays["joint_parents"])
        self.register_buffer("au_matrix", f32("au_matrix"))
        self.register_buffer("rotation_limits_deg", f32("rotation_limits_deg"))
        self.register_buffer("skinning_weights", f32("skinning_weights"))

        comps, std = f32("shape_components"), f32("shape_std")
        self.num_shape = comps.shape[0]
        self.num_expressions = len(self.expression_names)
        self.register_buffer("shape_std", std)
        shape_dirs = (comps * std[:, None, None]).reshape(self.num_shape, -1)  # (S, 3N) metres
        expr_dirs = f32("expression_basis").reshape(self.num_expressions, -1)  # (E, 3N)
        blocks = [shape_dirs, expr_dirs]
        self.has_pose_basis = "pose_basis" in arrays
        if self.has_pose_basis:
            blocks.append(f32("pose_basis").reshape(-1, 3 * n))
        # One contiguous (S + E [+ 9K], 3N) basis: the whole blendshape sum is one matmul.
        self.register_buffer("blend_basis", torch.cat(blocks, 0).contiguous())
        if self.has_pose_basis:
            # the pose correctives move the neck only (~1.4k of ~27k vertices in the default
            # model): forward reads them on those vertices' columns, not the zeros elsewhere
            pose = blocks[2].view(-1, n, 3)
            cols = torch.nonzero(pose.abs().amax(dim=(0, 2)) > 0).flatten()
            self.register_buffer("pose_columns", cols)
            self.register_buffer("pose_basis_columns",
                                 pose[:, cols].reshape(pose.shape[0], -1).contiguous())
        reg = f32("joint_regressor")  # (K, N)
        self.register_buffer("joint_regressor", reg)
        self.register_buffer("joints_template", reg @ self.template)  # (K, 3)
        self.register_buffer("joints_shapedirs", torch.einsum("kn,snc->skc", reg,
                                                              shape_dirs.reshape(-1, n, 3)))
        self.expr_personal = _PersonalBasis(arrays, "expr") if "expr_pca_vertices" in arrays else None
        self.pose_personal = _PersonalBasis(arrays, "pose") if "pose_pca_vertices" in arrays else None
        self.has_larynx = "larynx_maps" in arrays
        if self.has_larynx:
            self.register_buffer("larynx_maps", f32("larynx_maps"))
            self.register_buffer("larynx_uv_bounds", f32("larynx_uv_bounds"))
            self.register_buffer("larynx_vertices", i64("larynx_vertices"))
            self.register_buffer("larynx_coef_matrix", f32("larynx_coef_matrix"))
            self.register_buffer("larynx_coef_offset", f32("larynx_coef_offset"))
            self.larynx_v_per_metre = float(arrays["larynx_v_per_metre"])
            # The maps' chart: its own (format 2) or the atlas UVs of the larynx vertices.
            chart = (f32("larynx_vertex_uv") if "larynx_vertex_uv" in arrays
                     else self.vertex_uv[self.larynx_vertices])
            self.register_buffer("larynx_uv", chart)

    # ----------------------------------------------------------------------------- loading
    @classmethod
    def from_file(cls, path: str | Path) -> HackModel:
        """Load and validate a model file (see :mod:`hack_render.geometry.model_file`)."""
        arrays, meta = load_model_file(path)
        model = cls(arrays, meta)
        model.source_path = str(path)
        return model

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    # ---------------------------------------------------------------------- input handling
    def _params(self, beta, psi, theta, global_orient, transl, eta, tau) -> dict[str, torch.Tensor]:
        dtype, device = self.template.dtype, self.template.device
        given = {"beta": beta, "psi": psi, "theta": theta, "global_orient": global_orient,
                 "transl": transl, "eta": eta, "tau": tau}
        trailing = {"beta": None, "psi": (self.num_expressions,), "theta": (self.num_joints, 3),
                    "global_orient": (3,), "transl": (3,), "eta": (), "tau": ()}
        batch = 1
        out: dict[str, torch.Tensor] = {}
        for name, value in given.items():
            if value is None:
                continue
            if isinstance(value, str) and name == "psi":
                value = self.expression_vector(value)
            value = torch.as_tensor(value, dtype=dtype, device=device)
            if not torch.is_floating_point(value):
                value = value.to(dtype)
            want = trailing[name]
            if name == "beta":
                if value.ndim == 1:
                    value = value[None]
                if value.ndim != 2 or value.shape[1] > self.num_shape:
                    raise HackError(f"beta: expected shape (B, <= {self.num_shape}), found "
                                    f"{tuple(value.shape)}.")
            else:
                if value.ndim == len(want):
                    value = value[None]
                if value.ndim != len(want) + 1 or tuple(value.shape[1:]) != want:
                    raise HackError(f"{name}: expected shape (B, {', '.join(map(str, want))})"
                                    f"{' i.e. (B,)' if not want else ''}, found {tuple(value.shape)}.")
            if not torch.isfinite(value.detach()).all():
                raise HackError(f"{name}: contains NaN or inf values; pass finite numbers.")
            if value.shape[0] != 1:
                if batch != 1 and value.shape[0] != batch:
                    raise HackError(f"{name}: batch size {value.shape[0]} does not match "
                                    f"batch size {batch} of the other parameters.")
                batch = value.shape[0]
            out[name] = value
        zeros = {"beta": (0,), "psi": (self.num_expressions,), "theta": (self.num_joints, 3),
                 "global_orient": (3,), "transl": (3,), "eta": (), "tau": ()}
        for name, shp in zeros.items():
            if name not in out:
                out[name] = torch.zeros((batch,) + shp, dtype=dtype, device=device)
            elif out[name].shape[0] != batch:
                out[name] = out[name].expand((batch,) + tuple(out[name].shape[1:]))
        return out

    # ------------------------------------------------------------------------- expressions
    def expression_vector(self, spec: str | dict[str, float]) -> torch.Tensor:
        """psi (E,) from shape names and FACS action units.

        ``spec`` is a dict or a string like ``"AU12=0.7, jawOpen=0.4"``; AU entries add
        their shapes (table ``au_names`` / ``au_matrix``), shape names add themselves.
        """
        if isinstance(spec, str):
            items = {}
            for part in filter(None, (p.strip() for p in re.split(r"[,;]", spec))):
                if "=" not in part:
                    raise HackError(f"expression '{part}': expected NAME=VALUE, e.g. AU12=0.7 or jawOpen=0.4.")
                k, v = part.split("=", 1)
                try:
                    items[k.strip()] = float(v)
                except ValueError as exc:
                    raise HackError(f"expression '{part}': value {v!r} is not a number.") from exc
            spec = items
        psi = torch.zeros(self.num_expressions, dtype=self.template.dtype, device=self.template.device)
        for name, value in spec.items():
            value = float(value)
            if not np.isfinite(value):
                raise HackError(f"expression '{name}': value {value} is not finite.")
            if name in self.au_names:
                psi = psi + value * self.au_matrix[self.au_names.index(name)]
            elif name in self.expression_names:
                psi[self.expression_names.index(name)] += value
            else:
                close = [n for n in self.au_names + self.expression_names if n.lower() == name.lower()]
                hint = f" Did you mean {close[0]!r}?" if close else ""
                raise HackError(f"expression '{name}': unknown action unit or shape name.{hint} "
                                f"Known AUs: {', '.join(self.au_names)}; shape names: "
                                f"`hack-render model info` lists them.")
        return psi

    # ---------------------------------------------------------------------------- forward
    def rest_joints(self, beta: torch.Tensor) -> torch.Tensor:
        """J(beta) (B, K, 3): the regressor applied to T_bar + B_S(beta), in closed form."""
        s = beta.shape[1]
        return self.joints_template + torch.einsum("bs,skc->bkc", beta, self.joints_shapedirs[:s])

    def forward(self, beta=None, psi=None, theta=None, global_orient=None, transl=None,
                eta=None, tau=None, clamp_limits: bool = False) -> HackOutput:
        """Evaluate G. Shapes: beta (B, <=S), psi (B, E) or an expression string, theta
        (B, 8, 3) axis-angle c7-t1 ... o-c1, global_orient (B, 3) root axis-angle about the
        c7-t1 joint, transl (B, 3) metres, eta (B,), tau (B,) metres. Missing inputs are zero.
        With ``clamp_limits`` each joint is clamped to its anatomical limits first.
        """
        p = self._params(beta, psi, theta, global_orient, transl, eta, tau)
        if clamp_limits:
            from hack_render.geometry.skeleton import clamp_to_limits

            p["theta"] = clamp_to_limits(p["theta"])
        B = p["theta"].shape[0]
        beta = p["beta"]
        rot = local_rotations(p["theta"], p["global_orient"])  # (B, 9, 3, 3)
        feat = pose_feature(rot[:, 1:])  # (B, 72): joints only, not the global rotation
        beta_full = torch.nn.functional.pad(beta, (0, self.num_shape - beta.shape[1]))
        S, E, nb = self.num_shape, self.num_expressions, beta.shape[1]
        # beta's rows and the expression rows of the one basis (the shape rows past the
        # given betas, zero coefficients, are not read), then the pose rows on the
        # vertices they move
        blend = sparse_rows_product(p["psi"], self.blend_basis[S:S + E])
        if nb:
            blend = torch.addmm(blend, beta, self.blend_basis[:nb])
        rest = self.template + blend.view(B, -1, 3)
        if self.has_pose_basis:
            rest = _add_rows(rest, self.pose_columns,
                                  (feat @ self.pose_basis_columns).view(B, -1, 3))
        rest = self._personal_and_larynx(rest, beta_full, p["psi"], feat, p["eta"], p["tau"])
        joints = self.rest_joints(beta_full)
        return self._pose(rest, joints, rot, p["transl"])

    def _personal_and_larynx(self, rest, beta, psi, feat, eta, tau):
        if self.expr_personal is not None:
            rest = _add_rows(rest, self.expr_personal.vertices, self.expr_personal.apply(psi, beta))
        if self.pose_personal is not None:
            rest = _add_rows(rest, self.pose_personal.vertices, self.pose_personal.apply(feat, beta))
        if self.has_larynx:
            combined = _larynx.combine_maps(
                _larynx.larynx_coefficients(beta, self.larynx_coef_matrix, self.larynx_coef_offset),
                self.larynx_maps)
            rest = _add_rows(rest, self.larynx_vertices, self._larynx_sample(combined, eta, tau))
        return rest

    def larynx_displacement(self, beta: torch.Tensor | None = None, eta: torch.Tensor | None = None,
                            tau: torch.Tensor | None = None) -> torch.Tensor:
        """L(beta, eta, tau) at the larynx-region vertices (``larynx_vertices``): (B, M, 3)
        metres. Missing inputs: beta = 0, eta = 1 (the identity's mean larynx), tau = 0."""
        if not self.has_larynx:
            raise HackError("larynx_displacement: this model carries no larynx basis "
                            "(build one with `hack-render model build-v2`).")
        ref = next(t for t in (beta, eta, tau, self.template[None, :1, 0]) if t is not None)
        B = ref.shape[0]
        dd = dict(dtype=self.template.dtype, device=self.template.device)
        beta = torch.zeros(B, self.num_shape, **dd) if beta is None else beta
        beta = torch.nn.functional.pad(beta, (0, self.num_shape - beta.shape[1]))
        eta = torch.ones(B, **dd) if eta is None else eta
        tau = torch.zeros(B, **dd) if tau is None else tau
        combined = _larynx.combine_maps(_larynx.larynx_coefficients(
            beta, self.larynx_coef_matrix, self.larynx_coef_offset), self.larynx_maps)
        return self._larynx_sample(combined, eta, tau)

    def _larynx_sample(self, combined, eta, tau):
        return _larynx.sample_displacement(combined, self.larynx_uv,
                                           self.larynx_uv_bounds, eta, tau, self.larynx_v_per_metre)

    def _pose(self, rest, joints, rot, transl) -> HackOutput:
        root = joints[:, :1]  # the root (thorax) rotates about the c7-t1 joint
        nodes = torch.cat([root, joints], 1)
        posed_nodes, rel = rigid_transforms(rot, nodes, chain_parents(self.parents))
        verts = skin(rest, self.skinning_weights, rel) + transl[:, None]
        return HackOutput(vertices=verts, joints=posed_nodes[:, 1:] + transl[:, None],
                          rest_joints=joints, landmarks=verts[:, self.landmark_indices],
                          rest_vertices=rest)

    # ------------------------------------------------------------------------ personalise
    def personalize(self, beta) -> PersonalizedHack:
        """Precompute everything that depends on beta alone, for one identity.

        Returns a module whose forward takes (psi, theta, global_orient, transl, eta, tau)
        and equals this model's forward at that beta, without repeating shape, joint,
        personalised-basis and larynx-basis work.
        """
        return PersonalizedHack(self, beta)


class PersonalizedHack(nn.Module):
    """HACK for one fixed identity: "personalise once, animate many"."""

    def __init__(self, model: HackModel, beta):
        super().__init__()
        self.model = model
        p = model._params(beta, None, None, None, None, None, None)
        beta = p["beta"]
        if beta.shape[0] != 1:
            raise HackError(f"beta: personalize takes one identity, found batch {beta.shape[0]}.")
        with torch.no_grad():
            beta_full = torch.nn.functional.pad(beta, (0, model.num_shape - beta.shape[1]))
            s, e = model.num_shape, model.num_expressions
            v_shaped = model.template + (beta_full @ model.blend_basis[:s]).view(-1, 3)
            basis = model.blend_basis[s:].clone().view(-1, model.num_vertices, 3)  # (E [+ P], N, 3)
            if model.expr_personal is not None:
                basis[:e].index_add_(1, model.expr_personal.vertices, model.expr_personal.basis(beta_full))
            if model.pose_personal is not None:
                if not model.has_pose_basis:
                    basis = torch.cat([basis, basis.new_zeros(9 * model.num_joints, model.num_vertices, 3)])
                basis[e:].index_add_(1, model.pose_personal.vertices, model.pose_personal.basis(beta_full))
            self.uses_pose = basis.shape[0] > e
            self.register_buffer("v_shaped", v_shaped)
            self.register_buffer("basis", basis.reshape(basis.shape[0], -1).contiguous())
            self.register_buffer("joints", model.rest_joints(beta_full)[0])
            if model.has_larynx:
                self.register_buffer("larynx_combined", _larynx.combine_maps(
                    _larynx.larynx_coefficients(beta_full, model.larynx_coef_matrix,
                                                model.larynx_coef_offset), model.larynx_maps))

    def forward(self, psi=None, theta=None, global_orient=None, transl=None, eta=None,
                tau=None, clamp_limits: bool = False) -> HackOutput:
        m = self.model
        p = m._params(None, psi, theta, global_orient, transl, eta, tau)
        if clamp_limits:
            from hack_render.geometry.skeleton import clamp_to_limits

            p["theta"] = clamp_to_limits(p["theta"])
        B = p["theta"].shape[0]
        rot = local_rotations(p["theta"], p["global_orient"])
        coeffs = [p["psi"]] + ([pose_feature(rot[:, 1:])] if self.uses_pose else [])
        rest = self.v_shaped + (torch.cat(coeffs, 1) @ self.basis).view(B, -1, 3)
        if m.has_larynx:
            rest = _add_rows(rest, m.larynx_vertices,
                                  m._larynx_sample(self.larynx_combined.expand(B, -1, -1, -1),
                                                   p["eta"], p["tau"]))
        return m._pose(rest, self.joints.expand(B, -1, -1), rot, p["transl"])
