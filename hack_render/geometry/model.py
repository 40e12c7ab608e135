"""G(beta, psi, theta, eta, tau): the HACK geometry model (paper Eq. 2-3) as a torch module.

    T = T_bar + B_S(beta) + B_E(psi; E_beta) + B_P(theta; P_beta) + L(beta, eta, tau)
    G = LBS(T, J(beta), theta, W)

The module is stateless in its inputs (SMPL-X layer style): every parameter is a call
argument, missing ones are filled on the buffers' device and dtype (zeros, except eta = 1,
the identity's own larynx), and the batch size comes from the inputs. ``model.double()``
gives a float64 model for gradient checks.

The forward (:meth:`HackModel.forward`) is the fast path; :func:`reference_forward` is the
same model written plainly (dense bases, per-row personalised bases, skinning of every
vertex), kept beside it for teaching and as the reference the tests compare it with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from hack_render.errors import HackError
from hack_render.geometry import larynx as _larynx
from hack_render.geometry.expressions import (
    FACS_WITHOUT_SHAPES,  # noqa: F401  (re-exported)
    expression_weights,
)
from hack_render.geometry.lbs import (
    chain_parents,
    local_rotations,
    pose_feature,
    rigid_transforms,
    skin,
)
from hack_render.geometry.model_file import load_model_file
from hack_render.geometry.skeleton import clamp_to_limits


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
        """beta: (B, S) -> (B, C); betas beyond the first layer's width are ignored, and
        missing ones are zero (the first layer reads only the given betas' columns)."""
        s = min(beta.shape[1], self.w0.shape[1])
        x = torch.relu(torch.addmm(self.b0, beta[:, :s], self.w0[:, :s].T))
        x = torch.relu(torch.addmm(self.b1, x, self.w1.T))
        return torch.addmm(self.b2, x, self.w2.T)


# --------------------------------------------------------------------- basis products
def _add_rows_(rest: torch.Tensor, index: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """rest (B, N, 3) += delta (B, M, 3) at vertices ``index`` (M,), in place; returns rest.
    One identity (B = 1) adds along dim 0 of the (N, 3) view: index_add on dim 1 takes a
    slower path (forward + backward 1.4-2.3x on the CPU)."""
    if rest.shape[0] == 1:
        rest.view(rest.shape[1], 3).index_add_(0, index, delta.reshape(-1, 3))
    else:
        rest.index_add_(1, index, delta)
    return rest


def _nonzero_columns(coeffs: torch.Tensor) -> torch.Tensor | None:
    """Indices (n,) of the columns of coeffs (B, D) with a nonzero entry; None when all are."""
    used = coeffs.detach().ne(0).any(0)
    if bool(used.all()):
        return None
    return torch.nonzero(used).flatten()


def _runs(index: list[int]) -> list[tuple[int, int, int]]:
    """Maximal runs of consecutive integers in a sorted list: (position, first, end) each."""
    runs: list[tuple[int, int, int]] = []
    for pos, d in enumerate(index):
        if runs and runs[-1][2] == d:
            runs[-1] = (runs[-1][0], runs[-1][1], d + 1)
        else:
            runs.append((pos, d, d + 1))
    return runs


def _accumulate_rows_(out: torch.Tensor, coeffs: torch.Tensor, rows: torch.Tensor,
                      nz: torch.Tensor) -> None:
    """out (B, K) += coeffs[:, nz] @ rows[nz], reading only rows ``nz``. Each run of
    consecutive rows is one in-place product on a slice (no copy); when the runs are many
    and the output is tall, copying the used rows once moves fewer bytes than re-reading
    the output once per run."""
    idx = nz.tolist()
    runs = _runs(idx)
    if out.shape[0] * (len(runs) - 1) <= len(idx):
        for _, first, end in runs:
            out.addmm_(coeffs[:, first:end], rows[first:end])
    else:
        out.addmm_(coeffs.index_select(1, nz), rows.index_select(0, nz))


class _RowsProduct(torch.autograd.Function):
    """bias + coeffs @ rows, the forward reading only the rows of nonzero coefficients."""

    @staticmethod
    def forward(ctx, coeffs, rows, bias, nz):
        out = bias.expand(coeffs.shape[0], rows.shape[1]).clone()
        if len(nz):
            _accumulate_rows_(out, coeffs, rows, nz)
        ctx.save_for_backward(rows)
        ctx.bias_shape = tuple(bias.shape)
        return out

    @staticmethod
    def backward(ctx, g):
        (rows,) = ctx.saved_tensors
        grad_c = g @ rows.T if ctx.needs_input_grad[0] else None  # every row: zeros too
        grad_b = None
        if ctx.needs_input_grad[2]:
            shape = ctx.bias_shape
            grad_b = g if shape == tuple(g.shape) else g.sum(0).reshape(shape)
        return grad_c, None, grad_b, None


def rows_product(coeffs: torch.Tensor, rows: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``bias + coeffs @ rows``: coeffs (B, D), rows (D, K) a basis buffer, bias (K,),
    (1, K) or (B, K) -> a new (B, K) tensor, differentiable in coeffs and bias.

    The forward reads only the rows d where some ``coeffs[:, d]`` is nonzero: expression
    weights from FACS strings, and fitted ones (clamped to [0, 1] under an L1 prior), are
    mostly exact zeros. The backward reads every row, so a zero weight still gets its
    gradient (a fit can move it off zero)."""
    nz = _nonzero_columns(coeffs)
    if nz is None:
        return torch.addmm(bias, coeffs, rows)
    return _RowsProduct.apply(coeffs, rows, bias, nz)


def _personal_rows(coeffs, mean, w, comps, nz):
    """coeffs[:, nz] @ (mean + w comps)[nz] for one identity (w: (1, C)): per run of
    consecutive used rows, its basis rows by one (1, C) x (C, n K) product over a strided
    view (no copy), then one (B, n) x (n, K) product."""
    C, _, K = comps.shape
    out = None
    for _, first, end in _runs(nz.tolist()):
        n = end - first
        basis = torch.addmm(mean[first:end].reshape(1, n * K), w,
                            comps[:, first:end].reshape(C, n * K)).view(n, K)
        part = coeffs[:, first:end] @ basis
        out = part if out is None else out.add_(part)
    return coeffs.new_zeros(coeffs.shape[0], K) if out is None else out


class _PersonalProduct(torch.autograd.Function):
    """Per-row personalised product, unused rows skipped; see :func:`personal_product`."""

    @staticmethod
    def forward(ctx, coeffs, mean, w, comps, nz):
        ctx.save_for_backward(coeffs, mean, w, comps)
        if w.shape[0] == 1:
            return _personal_rows(coeffs, mean, w, comps, nz)
        B = coeffs.shape[0]
        C, _, K = comps.shape
        n = len(nz)
        x = (w[:, :, None] * coeffs[:, None, nz]).reshape(B, C * n)  # outer products, used rows
        return torch.addmm(coeffs[:, nz] @ mean[nz], x, comps.index_select(1, nz).view(C * n, K))

    @staticmethod
    def backward(ctx, g):
        coeffs, mean, w, comps = ctx.saved_tensors
        C, D, K = comps.shape
        # the one full read: G[b, c, d] = sum_k comps[c, d, k] g[b, k]
        G = (g @ comps.view(C * D, K).T).view(-1, C, D)
        grad_c = g @ mean.T + (G * w[:, :, None]).sum(1) if ctx.needs_input_grad[0] else None
        grad_w = (G * coeffs[:, None, :]).sum(2) if ctx.needs_input_grad[2] else None
        if grad_w is not None and w.shape[0] == 1:
            grad_w = grad_w.sum(0, keepdim=True)
        return grad_c, None, grad_w, None, None


def personal_product(coeffs: torch.Tensor, mean: torch.Tensor, w: torch.Tensor,
                     comps: torch.Tensor) -> torch.Tensor:
    """``coeffs[b] @ (mean + sum_c w[b, c] comps[c])`` per batch row -> (B, K).

    Args:
        coeffs: (B, D) expression weights or pose features.
        mean: (D, K) the personalised basis's mean.
        w: (B, C) per-row identity weights (the MLP of beta), or (1, C) when the whole
            batch shares one identity.
        comps: (C, D, K) components.

    Exact and differentiable in ``coeffs`` and ``w``; every form reads the components
    once per forward, and only the rows d with a nonzero ``coeffs[:, d]`` (the backward
    reads all rows, for the gradients of zero coefficients).

    * Distinct identities (and B = 1): one (B, C D) x (C D, K) product of the outer
      products ``w[b, c] coeffs[b, d]`` with the components, not one basis per row; its
      output is only (B, K), so at B = 1 it is a cache-friendly matrix-vector product.
    * One identity for a batch (``w`` of one row, B > 1): the identity's (D, K) basis once,
      then one (B, D) x (D, K) product (B C D K multiply-adds become C D K + B D K).
    """
    C, D, K = comps.shape
    B = coeffs.shape[0]
    grad = torch.is_grad_enabled() and (coeffs.requires_grad or w.requires_grad)
    if w.shape[0] == 1 and B > 1:
        nz = None if grad and coeffs.requires_grad else _nonzero_columns(coeffs)
        if nz is None:
            return coeffs @ (mean + (w @ comps.view(C, D * K)).view(D, K))
        return _personal_rows(coeffs, mean, w, comps, nz)
    nz = _nonzero_columns(coeffs)
    if nz is None:
        x = (w[:, :, None] * coeffs[:, None, :]).reshape(B, C * D)
        return torch.addmm(coeffs @ mean, x, comps.view(C * D, K))
    if not grad and w.shape[0] == 1:
        return _personal_rows(coeffs, mean, w, comps, nz)
    return _PersonalProduct.apply(coeffs, mean, w, comps, nz)


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

    def apply(self, coeffs: torch.Tensor, w: torch.Tensor, mean: torch.Tensor | None = None
              ) -> torch.Tensor:
        """Personal part of coeffs @ basis. coeffs: (B, D), w: (B or 1, C) from :attr:`mlp`
        -> (B, M, 3) metres; ``mean`` (D, 3M) replaces the stored mean (generic rows folded
        in)."""
        out = personal_product(coeffs, self.mean if mean is None else mean, w, self.components)
        return out.reshape(coeffs.shape[0], -1, 3)

    def basis(self, beta: torch.Tensor) -> torch.Tensor:
        """The personal deltas themselves for one identity. beta: (1, S) -> (D, M, 3)."""
        C, D, K = self.components.shape
        return (self.mean + (self.mlp(beta) @ self.components.view(C, D * K)).view(D, K)
                ).reshape(D, -1, 3)


def _skin_rows(v: torch.Tensor, weights: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """LBS of some vertices, as :func:`hack_render.geometry.lbs.skin` (the same blend of
    ``rel - I``), with the per-vertex 3x4 product written out elementwise (a batched 3x3 @
    3x1 matmul per vertex is slow). v: (B, M, 3), weights (M, K), rel (B, K, 4, 4)."""
    B, K = rel.shape[:2]
    eye = torch.eye(4, dtype=rel.dtype, device=rel.device)[:3]
    d = torch.matmul(weights, (rel[..., :3, :] - eye).reshape(B, K, 12)).view(B, -1, 3, 4)
    return _affine_columns(v, d, v + d[..., 3])


def _affine_columns(v: torch.Tensor, m: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """bias + m[..., :3] v per point, as multiply-adds of v's three columns (a 3-wide
    matmul, or a broadcast product and a sum, is 1.5-2x slower on the CPU). v: (B, M, 3),
    m: (B, M or 1, 3, >= 3), bias broadcastable to (B, M, 3) -> a new (B, M, 3) tensor."""
    out = torch.addcmul(bias, v[..., :1], m[..., 0])
    out.addcmul_(v[..., 1:2], m[..., 1])
    return out.addcmul_(v[..., 2:], m[..., 2])


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
        self._init_skinning_split()

        comps, std = f32("shape_components"), f32("shape_std")
        self.num_shape = comps.shape[0]
        self.num_expressions = len(self.expression_names)
        self.register_buffer("shape_std", std)
        shape_dirs = (comps * std[:, None, None]).reshape(self.num_shape, -1)  # (S, 3N) metres
        expr_dirs = f32("expression_basis").reshape(self.num_expressions, -1)  # (E, 3N)
        # One contiguous (E + S, 3N) basis, expressions first: the expression weights and
        # the given betas are one contiguous block of rows, so the whole blendshape sum is
        # one matrix product (betas past the given ones, zero, are not read).
        self.register_buffer("expr_shape_basis", torch.cat([expr_dirs, shape_dirs], 0).contiguous())
        self.has_pose_basis = "pose_basis" in arrays
        # format 3: each joint's corrective gated by its angle (None: plain R - I)
        self.pose_gate_rad = (math.radians(float(arrays["pose_gate_deg"]))
                              if "pose_gate_deg" in arrays else None)
        if self.has_pose_basis:
            # the pose correctives move the neck only (~1.4k of ~27k vertices in the default
            # model): stored and read on those vertices' columns, not the zeros elsewhere
            pose = f32("pose_basis").reshape(-1, n, 3)
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
        # generic pose rows on the same vertices as the personalised ones: one product
        # (the generic rows are added to the personalised mean at run time, in the model's
        # dtype, so a float64 model stays exact)
        self.pose_folded = (self.has_pose_basis and self.pose_personal is not None
                            and torch.equal(self.pose_columns, self.pose_personal.vertices))
        self._fold_pose_mean()
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

    def _fold_pose_mean(self) -> None:
        """``pose_mean_folded``: the personalised pose mean plus the generic pose rows on
        the same vertices (one (72, 3M) buffer, read once per forward), or None. Computed
        from the two buffers in their current dtype, so a float64 model's sum is exact in
        float64; rebuilt whenever the module's buffers are converted or moved (``_apply``:
        ``.double()``, ``.to()``), never per forward (an allocation of 1.2 MB and a pass
        over both buffers: 0.3-2 ms of a 6-16 ms B = 1 forward on a shared 2-core machine)."""
        folded = self.pose_personal.mean + self.pose_basis_columns if self.pose_folded else None
        self.register_buffer("pose_mean_folded", folded, persistent=False)

    def _apply(self, fn, *args, **kwargs):
        out = super()._apply(fn, *args, **kwargs)
        self._fold_pose_mean()
        return out

    def _init_skinning_split(self) -> None:
        """Most vertices move rigidly with one node (the default model: 25,347 of 26,719
        with the skull, o-c1): those are posed by one 3x3 product per batch row, and only
        the others are blended."""
        w = self.skinning_weights
        single = (w == 1).sum(0)
        node = int(single.argmax())
        rigid = (w[:, node] == 1) & ((w != 0).sum(1) == 1)
        self.rigid_node = node
        self.register_buffer("blended_vertices", torch.nonzero(~rigid).flatten(), persistent=False)
        self.register_buffer("blended_weights", w[~rigid].contiguous(), persistent=False)

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
    def _psi_value(self, value):
        """psi given as an expression string or dict (one row), or a list of them (and/or
        weight vectors), one per batch row -> (E,) or (B, E); anything else unchanged."""
        if isinstance(value, (str, dict)):
            return self.expression_vector(value)
        if isinstance(value, (list, tuple)) and any(isinstance(v, (str, dict)) for v in value):
            dd = {"dtype": self.template.dtype, "device": self.template.device}
            return torch.stack([self.expression_vector(v) if isinstance(v, (str, dict))
                                else torch.as_tensor(v, **dd) for v in value])
        return value

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
            if name == "psi":
                value = self._psi_value(value)
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
            if value.shape[0] != 1:
                if batch != 1 and value.shape[0] != batch:
                    raise HackError(f"{name}: batch size {value.shape[0]} does not match "
                                    f"batch size {batch} of the other parameters.")
                batch = value.shape[0]
            out[name] = value
        _check_finite(out)
        zeros = {"beta": (0,), "psi": (self.num_expressions,), "theta": (self.num_joints, 3),
                 "global_orient": (3,), "transl": (3,), "eta": (), "tau": ()}
        for name, shp in zeros.items():
            if name not in out:
                fill = _larynx.ETA_DEFAULT if name == "eta" else 0.0
                out[name] = torch.full((batch,) + shp, fill, dtype=dtype, device=device)
            elif out[name].shape[0] != batch:
                out[name] = out[name].expand((batch,) + tuple(out[name].shape[1:]))
        return out

    # ------------------------------------------------------------------------- expressions
    def expression_vector(self, spec: str | dict[str, float]) -> torch.Tensor:
        """psi (E,) from shape names and FACS action units.

        ``spec`` is a dict or a string like ``"AU12=0.7, jawOpen=0.4"``; AU entries add
        their shapes (table ``au_names`` / ``au_matrix``), shape names add themselves. For a
        batch, pass a list of specs (one per row) as ``psi`` to the forward.
        """
        psi = expression_weights(spec, self.expression_names, self.au_names,
                                 self.au_matrix.detach().cpu().numpy())
        return torch.as_tensor(psi, dtype=self.template.dtype, device=self.template.device)

    # ---------------------------------------------------------------------------- forward
    def rest_joints(self, beta: torch.Tensor) -> torch.Tensor:
        """J(beta) (B, K, 3): the regressor applied to T_bar + B_S(beta), in closed form."""
        s = beta.shape[1]
        k = self.joints_template.shape[0]
        return torch.addmm(self.joints_template.view(1, -1), beta,
                           self.joints_shapedirs[:s].reshape(s, 3 * k)).view(-1, k, 3)

    def forward(self, beta=None, psi=None, theta=None, global_orient=None, transl=None,
                eta=None, tau=None, clamp_limits: bool = False) -> HackOutput:
        """Evaluate G.

        Args:
            beta: (B, <=S) identity, N(0, 1) units; missing: 0 (the mean identity).
            psi: (B, E) expression weights, or an expression string / dict such as
                ``"AU12=0.7, jawOpen=0.4"`` (one row), or a list of them, one per row.
            theta: (B, 8, 3) axis-angle per joint c7-t1 ... o-c1, radians; missing: 0.
            global_orient: (B, 3) root axis-angle about the c7-t1 joint; missing: 0.
            transl: (B, 3) metres; missing: 0.
            eta: (B,) larynx size; missing: 1 (``larynx.ETA_DEFAULT``: the identity's own
                larynx, as on the CLI; 0 gives no larynx). Range ``larynx.ETA_RANGE``.
            tau: (B,) larynx vertical slide, metres, up positive; missing: 0. Range
                ``larynx.TAU_RANGE_M``.
            clamp_limits: clamp each joint to its rotation limits and eta, tau to their
                ranges first (``hack_render.geometry.limits`` warns or refuses instead).

        A batch whose rows share one identity (beta given as one row, or equal rows that
        need no gradient) builds its personalised bases, joints and larynx once.
        """
        p = self._params(beta, psi, theta, global_orient, transl, eta, tau)
        if clamp_limits:
            p["theta"] = clamp_to_limits(p["theta"])
            p["eta"], p["tau"] = _larynx.clamp_larynx(p["eta"], p["tau"])
        rot = local_rotations(p["theta"], p["global_orient"])  # (B, 9, 3, 3)
        beta = p["beta"]
        shared = _shares_identity(beta)
        ident = beta[:1] if shared else beta
        rest = self._rest(ident, p["psi"], self.pose_features(rot), p["eta"], p["tau"])
        joints = self.rest_joints(ident).expand(rest.shape[0], -1, -1)
        return self._pose(rest, joints, rot, p["transl"])

    def pose_features(self, rot: torch.Tensor) -> torch.Tensor:
        """The pose correctives' weights (B, 72) of node rotations rot (B, K + 1, 3, 3)
        (root first): each joint's ``R - I``, times its gate in a format-3 file
        (:func:`~hack_render.geometry.lbs.pose_feature`)."""
        return pose_feature(rot[:, 1:], self.pose_gate_rad)

    def _rest(self, beta, psi, feat, eta, tau) -> torch.Tensor:
        """T(beta, psi, theta, eta, tau) (B, N, 3). beta: (B, s) or (1, s) for a batch that
        shares one identity; psi (B, E); feat (B, 72) pose features; eta, tau (B,)."""
        B, E, nb = psi.shape[0], self.num_expressions, beta.shape[1]
        template = self.template.view(1, -1)
        if beta.shape[0] == 1 and B > 1:  # one identity: its shaped template once
            bias = torch.addmm(template, beta, self.expr_shape_basis[E:E + nb]) if nb else template
            flat = rows_product(psi, self.expr_shape_basis[:E], bias)
        else:
            flat = rows_product(torch.cat([psi, beta], 1), self.expr_shape_basis[:E + nb], template)
        rest = flat.view(B, -1, 3)
        # the MLPs and the larynx coefficients read only the given betas' columns
        if self.pose_personal is not None:
            w = self.pose_personal.mlp(beta)
            mean = self.pose_mean_folded  # None: not folded
            _add_rows_(rest, self.pose_personal.vertices, self.pose_personal.apply(feat, w, mean))
        if self.has_pose_basis and not self.pose_folded:
            _add_rows_(rest, self.pose_columns, (feat @ self.pose_basis_columns).view(B, -1, 3))
        if self.expr_personal is not None:
            w = self.expr_personal.mlp(beta)
            _add_rows_(rest, self.expr_personal.vertices, self.expr_personal.apply(psi, w))
        if self.has_larynx:
            combined = self._larynx_combined(beta).expand(B, -1, -1, -1)
            _add_rows_(rest, self.larynx_vertices, self._larynx_sample(combined, eta, tau))
        return rest

    def _larynx_combined(self, beta: torch.Tensor) -> torch.Tensor:
        """sum_i c_i(beta) L_i: (B, S) -> (B, 3, H, W) metres."""
        return _larynx.combine_maps(_larynx.larynx_coefficients(
            beta, self.larynx_coef_matrix, self.larynx_coef_offset), self.larynx_maps)

    def larynx_displacement(self, beta: torch.Tensor | None = None, eta: torch.Tensor | None = None,
                            tau: torch.Tensor | None = None) -> torch.Tensor:
        """L(beta, eta, tau) at the larynx-region vertices (``larynx_vertices``): (B, M, 3)
        metres. Missing inputs: beta = 0, eta = 1 (the identity's own larynx), tau = 0."""
        if not self.has_larynx:
            raise HackError("larynx_displacement: this model carries no larynx basis "
                            "(build one with `hack-render model build-v2`).")
        ref = next(t for t in (beta, eta, tau, self.template[None, :1, 0]) if t is not None)
        B = ref.shape[0]
        dd = {"dtype": self.template.dtype, "device": self.template.device}
        beta = torch.zeros(B, self.num_shape, **dd) if beta is None else beta
        beta = torch.nn.functional.pad(beta, (0, self.num_shape - beta.shape[1]))
        eta = torch.full((B,), _larynx.ETA_DEFAULT, **dd) if eta is None else eta
        tau = torch.zeros(B, **dd) if tau is None else tau
        return self._larynx_sample(self._larynx_combined(beta), eta, tau)

    def _larynx_sample(self, combined, eta, tau):
        return _larynx.sample_displacement(combined, self.larynx_uv,
                                           self.larynx_uv_bounds, eta, tau, self.larynx_v_per_metre)

    def _pose(self, rest, joints, rot, transl) -> HackOutput:
        root = joints[:, :1]  # the root (thorax) rotates about the c7-t1 joint
        nodes = torch.cat([root, joints], 1)
        posed_nodes, rel = rigid_transforms(rot, nodes, chain_parents(self.parents))
        # every vertex as if rigid with the node most vertices follow (one (B, N, 3) x
        # (B, 3, 3) product), then the blended vertices overwritten with their LBS
        a = rel[:, self.rigid_node, None, :3]  # (B, 1, 3, 4)
        verts = _affine_columns(rest, a, a[..., 3] + transl[:, None])
        idx = self.blended_vertices
        if len(idx):
            blended = _skin_rows(rest[:, idx], self.blended_weights, rel) + transl[:, None]
            if verts.shape[0] == 1:
                verts.view(-1, 3).index_copy_(0, idx, blended[0])
            else:
                verts.index_copy_(1, idx, blended)
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


def _check_finite(given: dict[str, torch.Tensor]) -> None:
    """Raise naming the first input with a NaN or inf. One check over all inputs at once
    (a handful of small ops per input otherwise, a tenth of a B = 1 forward's overhead)."""
    if not given:
        return
    flat = torch.cat([v.detach().reshape(-1) for v in given.values()])
    if bool(torch.isfinite(flat).all()):
        return
    for name, value in given.items():
        if not torch.isfinite(value.detach()).all():
            raise HackError(f"{name}: contains NaN or inf values; pass finite numbers.")


def _shares_identity(beta: torch.Tensor) -> bool:
    """Whether a (B, s) beta is one identity for the whole batch, so that per-identity work
    may be done once: one row, a row expanded over the batch (stride 0: the gradient of the
    one row is what autograd wants), or equal rows that need no gradient."""
    if beta.shape[0] == 1 or beta.shape[1] == 0 or beta.stride(0) == 0:
        return True
    if torch.is_grad_enabled() and beta.requires_grad:
        return False
    return bool((beta == beta[:1]).all())


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
            e, n = model.num_expressions, model.num_vertices
            v_shaped = model.template.view(1, -1) + beta_full @ model.expr_shape_basis[e:]
            expr = model.expr_shape_basis[:e].clone().view(e, n, 3)  # (E, N, 3)
            if model.expr_personal is not None:
                expr.index_add_(1, model.expr_personal.vertices, model.expr_personal.basis(beta_full))
            # pose correctives on the union of the generic and personalised columns
            parts = []
            if model.has_pose_basis:
                parts.append((model.pose_columns, model.pose_basis_columns.view(-1, len(model.pose_columns), 3)))
            if model.pose_personal is not None:
                parts.append((model.pose_personal.vertices, model.pose_personal.basis(beta_full)))
            self.uses_pose = bool(parts)
            if parts:
                cols = torch.unique(torch.cat([c for c, _ in parts]))
                pose = torch.zeros(9 * model.num_joints, n, 3, dtype=expr.dtype, device=expr.device)
                for c, b in parts:
                    pose.index_add_(1, c, b)
                self.register_buffer("pose_columns", cols)
                self.register_buffer("pose_basis", pose[:, cols].reshape(pose.shape[0], -1).contiguous())
            self.register_buffer("v_shaped", v_shaped)
            self.register_buffer("basis", expr.reshape(e, -1))
            self.register_buffer("joints", model.rest_joints(beta_full)[0])
            if model.has_larynx:
                self.register_buffer("larynx_combined", model._larynx_combined(beta_full))

    def forward(self, psi=None, theta=None, global_orient=None, transl=None, eta=None,
                tau=None, clamp_limits: bool = False) -> HackOutput:
        """As :meth:`HackModel.forward` at the personalised beta (same defaults)."""
        m = self.model
        p = m._params(None, psi, theta, global_orient, transl, eta, tau)
        if clamp_limits:
            p["theta"] = clamp_to_limits(p["theta"])
            p["eta"], p["tau"] = _larynx.clamp_larynx(p["eta"], p["tau"])
        B = p["theta"].shape[0]
        rot = local_rotations(p["theta"], p["global_orient"])
        rest = rows_product(p["psi"], self.basis, self.v_shaped).view(B, -1, 3)
        if self.uses_pose:
            _add_rows_(rest, self.pose_columns,
                       (m.pose_features(rot) @ self.pose_basis).view(B, -1, 3))
        if m.has_larynx:
            _add_rows_(rest, m.larynx_vertices,
                       m._larynx_sample(self.larynx_combined.expand(B, -1, -1, -1),
                                        p["eta"], p["tau"]))
        return m._pose(rest, self.joints.expand(B, -1, -1), rot, p["transl"])


def reference_forward(model: HackModel, beta=None, psi=None, theta=None, global_orient=None,
                      transl=None, eta=None, tau=None) -> HackOutput:
    """G written plainly, for teaching and as the tests' reference for the fast forward:
    dense (3N-wide) shape, expression and pose bases, each row's personalised bases built
    in full, the larynx per row, and every vertex skinned by :func:`lbs.skin`. Same inputs
    and defaults as :meth:`HackModel.forward` (no ``clamp_limits``); slow."""
    m = model
    p = m._params(beta, psi, theta, global_orient, transl, eta, tau)
    B, n, E = p["theta"].shape[0], m.num_vertices, m.num_expressions
    beta = torch.nn.functional.pad(p["beta"], (0, m.num_shape - p["beta"].shape[1]))
    beta = beta.expand(B, -1)
    rot = local_rotations(p["theta"], p["global_orient"])
    feat = pose_feature(rot[:, 1:], m.pose_gate_rad)
    shape_dirs, expr_dirs = m.expr_shape_basis[E:], m.expr_shape_basis[:E]
    rest = m.template + (beta @ shape_dirs + p["psi"] @ expr_dirs).view(B, n, 3)
    if m.has_pose_basis:  # the dense (72, N, 3) pose basis, zeros off the stored columns
        dense = torch.zeros(feat.shape[1], n, 3, dtype=rest.dtype, device=rest.device)
        dense[:, m.pose_columns] = m.pose_basis_columns.view(feat.shape[1], -1, 3)
        rest = rest + (feat @ dense.view(feat.shape[1], -1)).view(B, n, 3)
    for pb, coeffs in ((m.expr_personal, p["psi"]), (m.pose_personal, feat)):
        if pb is None:
            continue
        rows = []
        for b in range(B):  # each row's own basis: mean + sum_c w_c components_c
            w = pb.mlp(beta[b:b + 1])[0]
            basis = pb.mean + torch.einsum("c,cdk->dk", w, pb.components)
            rows.append((coeffs[b] @ basis).view(-1, 3))
        rest = rest.index_add(1, pb.vertices, torch.stack(rows))
    if m.has_larynx:
        lar = m._larynx_sample(m._larynx_combined(beta), p["eta"], p["tau"])
        rest = rest.index_add(1, m.larynx_vertices, lar)
    joints = m.rest_joints(beta)
    nodes = torch.cat([joints[:, :1], joints], 1)
    posed, rel = rigid_transforms(rot, nodes, chain_parents(m.parents))
    verts = skin(rest, m.skinning_weights, rel) + p["transl"][:, None]
    return HackOutput(vertices=verts, joints=posed[:, 1:] + p["transl"][:, None],
                      rest_joints=joints, landmarks=verts[:, m.landmark_indices],
                      rest_vertices=rest)
