"""G(beta, psi, theta, eta, tau): the HACK geometry model (paper Eq. 2-3) as a torch module.

    T = T_bar + B_S(beta) + B_E(psi; E_beta) + B_P(theta; P_beta) + F(beta, theta)
        + L(beta, eta, tau)
    G = LBS(T, J(beta), theta, W)

(F: the flexion block of a format-5 file, :mod:`hack_render.geometry.flex_block`.)

The module is stateless in its inputs (SMPL-X layer style): every parameter is a call
argument, missing ones are filled on the buffers' device and dtype (zeros, except eta = 1,
the identity's own larynx), and the batch size comes from the inputs. ``model.double()``
gives a float64 model for gradient checks.

The forward (:meth:`HackModel.forward`) is the fast path; ``reference.reference_forward`` is
the same model written plainly (dense bases, per-row personalised bases, skinning of every
vertex), kept for teaching and as the reference the tests compare it with. The inputs'
checks and defaults are ``arguments.py``'s, the one-identity module (:meth:`personalize`)
``personalized.py``'s.
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
from hack_render.geometry.arguments import forward_arguments, shares_identity
from hack_render.geometry.expressions import (
    FACS_WITHOUT_SHAPES,  # noqa: F401  (re-exported)
    expression_weights,
)
from hack_render.geometry.lbs import (
    chain_parents,
    is_path,
    local_rotations,
    path_transforms,
    pose_feature,
    rigid_transforms,
)
from hack_render.geometry.model_file import load_model_file
from hack_render.geometry.personalized import PersonalizedHack
from hack_render.geometry.products import (
    FlexBlock,
    PersonalBasis,
    add_rows_,
    affine_columns,
    expression_products,
    nonzero_columns,
    rigid_apply,
    rigid_block,
    rigid_operator,
    rows_product,
    skin_blend,
)
from hack_render.geometry.skeleton import clamp_to_limits
from hack_render.threads import beside, bulk_work, small_work, spare_core


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


class HackModel(nn.Module):
    """The HACK geometry model. Build with :meth:`from_file` or :func:`load_default_model`."""

    #: One-row forwards make their expression products on the helper thread (_components_beside)
    overlap_products: bool = True

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
        # format 4: the gate also opened by the chain's net rotation (0: by each joint's own)
        self.pose_gate_chain = float(arrays.get("pose_gate_chain", 0.0))
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
        self.register_buffer("joints_shapedirs", torch.einsum(
            "kn,snc->skc", reg, shape_dirs.reshape(-1, n, 3)).contiguous())  # rows as views
        self.expr_personal = PersonalBasis(arrays, "expr") if "expr_pca_vertices" in arrays else None
        self.pose_personal = PersonalBasis(arrays, "pose") if "pose_pca_vertices" in arrays else None
        self.flex = FlexBlock(arrays) if "flex_basis" in arrays else None  # format 5
        # generic pose rows on the same vertices as the personalised ones: one product
        # (the generic rows are added to the personalised mean at run time, in the model's
        # dtype, so a float64 model stays exact)
        self.pose_folded = (self.has_pose_basis and self.pose_personal is not None
                            and torch.equal(self.pose_columns, self.pose_personal.vertices))
        if self.expr_personal is not None:
            # B = 1 (:meth:`_rest_single`): the generic expression rows' columns on the
            # vertices some expression moves, less the personalised vertices (their
            # generic rows are folded into the personal mean: ``expr_psi_rows``)
            moved = expr_dirs.view(self.num_expressions, n, 3).ne(0).any(0).any(1)
            moved[self.expr_personal.vertices] = False
            verts = torch.nonzero(moved).flatten()
            xyz = torch.arange(3)
            self.register_buffer("expr_col_index", (3 * verts[:, None] + xyz).flatten(),
                                 persistent=False)
            self.register_buffer("expr_personal_cols",
                                 (3 * self.expr_personal.vertices[:, None] + xyz).flatten(),
                                 persistent=False)
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
        """Derived buffers, computed from the stored ones in their current dtype (so a
        float64 model's are exact in float64) and rebuilt whenever the module's buffers
        are converted or moved (``_apply``: ``.double()``, ``.to()``), never per forward:

        * ``pose_mean_folded``: the personalised pose mean plus the generic pose rows on
          the same vertices (one (72, 3M) buffer, read once per forward), or None (an
          allocation of 1.2 MB and a pass over both buffers: 0.3-2 ms of a 6-16 ms B = 1
          forward on a shared 2-core machine).
        * ``pose_bias_basis`` / ``expr_bias_basis``: a personalised basis at w = b2,
          ``mean (+ generic rows) + b2 @ components`` (:meth:`PersonalBasis.bias_basis`),
          used exactly when the MLP's second hidden layer is zero for every row
          (:meth:`hack_render.geometry.products.MLP.weights`). The default model's M_P is such an MLP for every identity
          (its hidden units died in learning: see its metadata), so its 10 MB of
          components are not read per forward; M_E is not, and its stay as they are.
        """
        folded = self.pose_personal.mean + self.pose_basis_columns if self.pose_folded else None
        self.register_buffer("pose_mean_folded", folded, persistent=False)
        psi_rows = None
        if self.expr_personal is not None:
            E = self.num_expressions
            gen = self.expr_shape_basis[:E]
            psi_rows = torch.cat([gen.index_select(1, self.expr_col_index), self.expr_personal.mean
                                  + gen.index_select(1, self.expr_personal_cols)], 1)
        self.register_buffer("expr_psi_rows", psi_rows, persistent=False)
        for name, pb, mean in (("pose_bias_basis", self.pose_personal, folded),
                               ("expr_bias_basis", self.expr_personal, None)):
            with torch.no_grad():
                basis = None if pb is None else pb.bias_basis(mean)
            self.register_buffer(name, basis, persistent=False)

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
    def _params(self, beta, psi, theta, global_orient, transl, eta, tau) -> dict[str, torch.Tensor]:
        """The forward's inputs checked, defaulted and broadcast (:func:`arguments.forward_arguments`)."""
        return forward_arguments(self, beta, psi, theta, global_orient, transl, eta, tau)

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
        # one row: torch on one thread but for the basis products (``threads.small_work``;
        # at S = 20, interleaved with smplx on 2 cores, 4.66 -> 4.44 ms: docs/model.md)
        # B = 1: the expression rows (60 MB) stream on the helper thread meanwhile (docs/model.md)
        early = self._components_beside(p["psi"], p["beta"])
        with small_work(p["theta"].shape[0] == 1):
            rot = local_rotations(p["theta"], p["global_orient"])  # (B, 9, 3, 3)
            beta = p["beta"]
            shared = shares_identity(beta)
            ident = beta[:1] if shared else beta
            # the small operations first, the basis products last: a product streams tens
            # of MB through the caches, and small operations after it run cold (a chain of
            # them after a 72 MB read measured 2.6x its warm CPU time)
            joints = self.rest_joints(ident).expand(rot.shape[0], -1, -1)
            posing = self._posing(joints, rot, p["transl"])
            flex = self.flex_delta(ident, rot, posing[3]) if self.flex is not None else None
            rest = self._rest(ident, p["psi"], self.pose_features(rot), p["eta"], p["tau"],
                              flex, early)
            return self._pose(rest, joints, rot, p["transl"], posing)

    def _components_beside(self, psi: torch.Tensor, beta: torch.Tensor) -> tuple | None:
        """(used rows, future of :meth:`_rest_single`'s (Y, P, shaped template or None: beta
        needs a gradient), made on the helper thread:
        :func:`hack_render.threads.beside`) for one CPU row with no gradient to psi and two
        or more torch threads and a core idle (:func:`~hack_render.threads.spare_core`), when
        :attr:`overlap_products`; else None (the same, here)."""
        if (psi.shape[0] != 1 or self.expr_psi_rows is None or not self.overlap_products
                or psi.device.type != "cpu" or torch.get_num_threads() < 2
                or (torch.is_grad_enabled() and psi.requires_grad) or not spare_core()):
            return None
        psi, nb = psi.detach(), beta.shape[1]
        shaped = None if torch.is_grad_enabled() and beta.requires_grad else (
            self.template.view(1, -1), beta, self.expr_shape_basis[psi.shape[1]:psi.shape[1] + nb])
        nz = nonzero_columns(psi)
        return nz, beside(expression_products, self.expr_psi_rows, self.expr_personal.rows, psi,
                          nz, shaped)

    def flex_delta(self, beta: torch.Tensor | None, rot: torch.Tensor, rel: torch.Tensor,
                   rows: torch.Tensor | None = None) -> tuple | None:
        """The flexion block's (format 5) (vertices, offsets (B, M, 3)), or None where no
        hat acts: identities beta (B or 1, s), node rotations rot (B, K + 1, 3, 3) (root
        first), the nodes' transforms ``rel`` (their world rotations give the joints' net
        rotation in one product); ``rows``: one identity's
        :meth:`FlexBlock.identity_rows`, precomputed."""
        r = rel[..., :3, :3]
        net = r[:, 0].transpose(-1, -2) @ r[:, -1]  # the root's undone: R_1 ... R_K
        d = self.flex.offsets(beta, rot[:, 1:], rows, net)
        return None if d is None else (self.flex.vertices, d)

    def pose_features(self, rot: torch.Tensor) -> torch.Tensor:
        """The pose correctives' weights (B, 72) of node rotations rot (B, K + 1, 3, 3)
        (root first): each joint's ``R - I``, times its gate in a format-3 file (format 4:
        also opened by the chain's net rotation; :func:`~hack_render.geometry.lbs.pose_feature`)."""
        return pose_feature(rot[:, 1:], self.pose_gate_rad, self.pose_gate_chain)

    def _rest(self, beta, psi, feat, eta, tau, flex=None, early=None) -> torch.Tensor:
        """T(beta, psi, theta, eta, tau) (B, N, 3). beta: (B, s) or (1, s) for a batch that
        shares one identity; psi (B, E); feat (B, 72) pose features; eta, tau (B,); flex:
        the flexion block's (vertices, offsets) (:meth:`flex_delta`) or None; early:
        :meth:`_components_beside`'s (used rows, future) or None."""
        B, E, nb = psi.shape[0], self.num_expressions, beta.shape[1]
        template = self.template.view(1, -1)
        # the small terms (MLPs, pose correctives, larynx; they read only the given betas'
        # columns) before the expression and shape products, as in :meth:`forward`
        deltas = [] if flex is None else [flex]  # (vertex indices, (B, M, 3) deltas)
        pp, ep = self.pose_personal, self.expr_personal
        if pp is not None:
            w, constant = pp.mlp.weights(beta)
            if constant:  # w = b2 for every row, no gradient in beta: the basis at b2
                bb = self.pose_bias_basis
                d = rows_product(feat, bb, bb.new_zeros(bb.shape[1])).view(B, -1, 3)
            else:
                d = pp.apply(feat, w, self.pose_mean_folded)
            deltas.append((pp.vertices, d))
        if self.has_pose_basis and not self.pose_folded:
            deltas.append((self.pose_columns, (feat @ self.pose_basis_columns).view(B, -1, 3)))
        if self.has_larynx:
            combined = self._larynx_combined(beta).expand(B, -1, -1, -1)
            deltas.append((self.larynx_vertices, self._larynx_sample(combined, eta, tau)))
        w_e, constant_e = ep.mlp.weights(beta) if ep is not None else (None, False)
        single = B == 1 and self.expr_psi_rows is not None
        if early is not None:
            nz, components = early
        elif single:
            nz, components = nonzero_columns(psi), None
            # zero weights with gradients: the general path (its backward reads every row)
            single = nz is None or not (torch.is_grad_enabled() and psi.requires_grad)
        if single:
            rest = self._rest_single(beta, psi, nz, w_e, components)
        else:
            with bulk_work():
                if beta.shape[0] == 1 and B > 1:  # one identity: its shaped template once
                    bias = (torch.addmm(template, beta, self.expr_shape_basis[E:E + nb]) if nb
                            else template)
                    flat = rows_product(psi, self.expr_shape_basis[:E], bias)
                else:
                    flat = rows_product(torch.cat([psi, beta], 1),
                                        self.expr_shape_basis[:E + nb], template)
                rest = flat.view(B, -1, 3)
                if ep is not None:
                    if constant_e:
                        bb = self.expr_bias_basis
                        d = rows_product(psi, bb, bb.new_zeros(bb.shape[1])).view(B, -1, 3)
                    else:
                        d = ep.apply(psi, w_e)
            if ep is not None:
                add_rows_(rest, ep.vertices, d)
        for index, d in deltas:
            add_rows_(rest, index, d)
        return rest

    def _rest_single(self, beta, psi, nz, w, components=None) -> torch.Tensor:
        """The shape and expression terms of :meth:`_rest` for one row (B = 1): (1, N, 3).

        The expression weights multiply three things: the generic expression rows, the
        personalised basis's mean and its components. They go first, in two
        matrix-vector products over the used rows (``nz``; None: all): one over
        :attr:`expr_psi_rows` (the generic rows on the vertices some expression moves,
        then the personal mean with the generic rows of its vertices folded in) and one
        over the components (D, C K), giving P (C, K); then the personal deltas are
        ``mean part + w @ P`` (w: M_E's weights of beta, (1, C)). The generic rows' exact zeros (the vertices no
        expression moves, a quarter of the default model's) are not read. Differentiable
        (plain autograd ops; :meth:`_rest` sends zero weights that need gradients to the
        general path). ``components``: a future of (Y, P, flat) (:meth:`_components_beside`)."""
        E, nb = self.num_expressions, beta.shape[1]
        pb = self.expr_personal
        if components is None:
            with bulk_work():
                Y, P, flat = expression_products(self.expr_psi_rows, pb.rows, psi, nz)
        else:
            Y, P, flat = components.result()
        # the shaped template last: the (1, 3N) rest mesh is then still in the cache for
        # the additions and the posing that follow
        if flat is None:
            flat = torch.addmm(self.template.view(1, -1), beta, self.expr_shape_basis[E:E + nb])
        if Y is None:
            return flat.view(1, -1, 3)
        m = self.expr_col_index.shape[0]
        flat.view(-1).index_add_(0, self.expr_col_index, Y[0, :m])
        personal = torch.addmm(Y[:, m:], w, P.view(pb.rows.shape[1:]))
        return add_rows_(flat.view(1, -1, 3), pb.vertices, personal.view(1, -1, 3))

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

    def _posing(self, joints, rot, transl) -> tuple:
        """What :meth:`_pose` needs that does not depend on the rest mesh: the posed nodes,
        the chain's transforms, the rigid node's operator and the blended vertices' blend."""
        root = joints[:, :1]  # the root (thorax) rotates about the c7-t1 joint
        nodes = torch.cat([root, joints], 1)
        parents = chain_parents(self.parents)
        if is_path(parents):  # rel: (B, K, 3, 4), all that posing reads
            posed_nodes, rel = path_transforms(rot, nodes)
        else:
            posed_nodes, rel = rigid_transforms(rot, nodes, parents)
        rigid = rigid_operator(rel[:, self.rigid_node, :3], transl,
                                rigid_block(self.num_vertices))
        blend = skin_blend(self.blended_weights, rel) if len(self.blended_vertices) else None
        return posed_nodes, rigid, blend, rel

    def _pose(self, rest, joints, rot, transl, posing=None) -> HackOutput:
        posed_nodes, rigid, blend, _ = posing or self._posing(joints, rot, transl)
        # every vertex as if rigid with the node most vertices follow (one (B, N, 3) x
        # (B, 3, 3) product), then the blended vertices overwritten with their LBS
        verts = rigid_apply(rest, rigid)
        idx = self.blended_vertices
        if len(idx):
            v = rest[:, idx]
            blended = affine_columns(v, blend, v + blend[..., 3]) + transl[:, None]
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
