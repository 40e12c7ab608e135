"""The forward's building blocks: the personalised bases' MLPs and products, the sparse
row products with their hand-written gradients, and the column-wise skinning and rigid
posing kernels. :mod:`hack_render.geometry.model` assembles them into G(beta, psi, theta,
eta, tau); each is exact against the dense formula (tests/test_geometry.py,
tests/test_forward_speed_equivalence.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from hack_render.geometry.lbs import flex_weights


class MLP(nn.Module):
    """Three linear layers with ReLU between them (paper Sec. 5.1: 64 units)."""

    def __init__(self, w0, b0, w1, b1, w2, b2):
        super().__init__()
        for i, (w, b) in enumerate(((w0, b0), (w1, b1), (w2, b2))):
            self.register_buffer(f"w{i}", w)
            self.register_buffer(f"b{i}", b)

    def forward(self, beta: torch.Tensor) -> torch.Tensor:
        """beta: (B, S) -> (B, C); betas beyond the first layer's width are ignored, and
        missing ones are zero (the first layer reads only the given betas' columns)."""
        return self.weights(beta)[0]

    def weights(self, beta: torch.Tensor) -> tuple[torch.Tensor, bool]:
        """(w, constant): w = forward(beta); ``constant`` when the second hidden layer is
        zero in every row, so that w is exactly the output bias b2 (0 @ w2 + b2) and its
        gradient in beta is zero (ReLU's is zero where it clips): the model's personalised
        basis is then the identity-independent ``mean + b2 @ components``."""
        s = min(beta.shape[1], self.w0.shape[1])
        x = torch.relu(torch.addmm(self.b0, beta[:, :s], self.w0[:, :s].T))
        x = torch.relu(torch.addmm(self.b1, x, self.w1.T))
        return torch.addmm(self.b2, x, self.w2.T), not bool(x.detach().any())


# --------------------------------------------------------------------- basis products
def add_rows_(rest: torch.Tensor, index: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """rest (B, N, 3) += delta (B, M, 3) at vertices ``index`` (M,), in place; returns rest.
    One identity (B = 1) adds along dim 0 of the (N, 3) view: index_add on dim 1 takes a
    slower path (forward + backward 1.4-2.3x on the CPU)."""
    if rest.shape[0] == 1:
        rest.view(rest.shape[1], 3).index_add_(0, index, delta.reshape(-1, 3))
    else:
        rest.index_add_(1, index, delta)
    return rest


def nonzero_columns(coeffs: torch.Tensor) -> torch.Tensor | None:
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
    nz = nonzero_columns(coeffs)
    if nz is None:
        return torch.addmm(bias, coeffs, rows)
    return _RowsProduct.apply(coeffs, rows, bias, nz)


def row_runs(nz: torch.Tensor | None, D: int) -> list[tuple[int, int, int]]:
    """Runs (position, first, end) of the used rows ``nz``, or one run of all D rows."""
    return [(0, 0, D)] if nz is None else _runs(nz.tolist())


def expression_products(psi_rows: torch.Tensor, rows: torch.Tensor, coeffs: torch.Tensor,
                        nz: torch.Tensor | None, shaped: tuple | None = None) -> tuple:
    """A one-row forward's expression products (:meth:`HackModel._rest_single`), each one
    product per run of used rows (:func:`row_runs`), summed in order: Y = coeffs[:, nz] @
    psi_rows[nz] (1, M) and P = coeffs[:, nz] @ rows[nz] viewed (n, C K), (1, C K), and
    ``torch.addmm(*shaped)`` (the shaped template; None when ``shaped`` is None).
    psi_rows: (D, M); rows: (D, C, K); coeffs: (1, D); nz: the used rows (None: all).
    Y and P are None when no row is used."""
    Y = None
    runs = row_runs(nz, rows.shape[0])
    for _, first, end in runs:
        y = coeffs[:, first:end] @ psi_rows[first:end]
        Y = y if Y is None else Y + y
    return Y, _components_one_row(coeffs, rows, runs), \
        None if shaped is None else torch.addmm(*shaped)


def _components_one_row(coeffs, rows, runs):
    """P = coeffs (1, D) @ rows (D, C, K) viewed (D, C K) over the used ``runs``
    (:func:`row_runs`), one product per run summed in order: (1, C K); None for no run."""
    _, C, K = rows.shape
    P = None
    for _, first, end in runs:
        p = coeffs[:, first:end] @ rows[first:end].view(end - first, C * K)
        P = p if P is None else P + p
    return P


def _personal_forward(coeffs, mean, w, rows, nz):
    """coeffs[:, nz] @ (mean + w comps)[nz] per batch row, reading only the used rows
    (all rows when nz is None). rows: (D, C, K), each basis row's C components together,
    so every run of consecutive used rows is one contiguous block (a view, no copy).

    * B = 1: the expression weights first, ``P = coeffs @ rows.view(D, C K)`` (C, K) by one
      matrix-vector product over wide rows (the layout the CPU streams fastest), then
      ``w @ P``: C K + D C K multiply-adds and one read of the used rows.
    * Distinct identities (B > 1): the outer products ``coeffs[b, d] w[b, c]`` (B, D C) by
      the (D C, K) rows, one matrix product (the rows read once for the whole batch).
    * One identity for a batch (``w`` of one row, B > 1): its (n, K) basis on the used
      rows once, then one (B, n) x (n, K) product.
    Differentiable when ``nz`` is None (plain autograd ops)."""
    D, C, K = rows.shape
    B = coeffs.shape[0]
    runs = row_runs(nz, D)
    used = coeffs if nz is None else coeffs.index_select(1, nz)
    used_mean = mean if nz is None else mean.index_select(0, nz)
    if B == 1:
        P = _components_one_row(coeffs, rows, runs)
        if P is None:
            return coeffs.new_zeros(B, K)
        return torch.addmm(used @ used_mean, w, P.view(C, K))
    if w.shape[0] == 1:
        parts = [torch.matmul(w[0], rows[first:end]) for _, first, end in runs]
        if not parts:
            return coeffs.new_zeros(B, K)
        basis = used_mean + (parts[0] if len(parts) == 1 else torch.cat(parts, 0))
        return used @ basis
    out = used @ used_mean
    for pos, first, end in runs:
        n = end - first
        x = (used[:, pos:pos + n, None] * w[:, None, :]).reshape(B, n * C)
        out = torch.addmm(out, x, rows[first:end].view(n * C, K))
    return out


class _PersonalProduct(torch.autograd.Function):
    """Per-row personalised product, unused rows skipped forward; see :func:`personal_product`."""

    @staticmethod
    def forward(ctx, coeffs, mean, w, rows, nz):
        ctx.save_for_backward(coeffs, mean, w, rows)
        return _personal_forward(coeffs, mean, w, rows, nz)

    @staticmethod
    def backward(ctx, g):
        coeffs, mean, w, rows = ctx.saved_tensors
        D, C, K = rows.shape
        # the one full read: G[b, d, c] = sum_k rows[d, c, k] g[b, k]
        G = (g @ rows.view(D * C, K).T).view(-1, D, C)
        grad_c = g @ mean.T + (G * w[:, None, :]).sum(2) if ctx.needs_input_grad[0] else None
        grad_w = (G * coeffs[:, :, None]).sum(1) if ctx.needs_input_grad[2] else None
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
        comps: (C, D, K) components; fastest as the (C, D, K) view
            ``rows.transpose(0, 1)`` of a contiguous (D, C, K) ``rows`` (how
            :class:`PersonalBasis` stores them: each basis row's components together);
            any other layout is copied into that one first.

    Exact and differentiable in ``coeffs`` and ``w``; every form reads the components
    once per forward, and only the rows d with a nonzero ``coeffs[:, d]`` (the backward
    reads all rows, for the gradients of zero coefficients). See :func:`_personal_forward`
    for the contraction orders (B = 1: the expression weights first).
    """
    rows = comps.transpose(0, 1)
    if not rows.is_contiguous():
        rows = rows.contiguous()
    B = coeffs.shape[0]
    grad = torch.is_grad_enabled() and (coeffs.requires_grad or w.requires_grad)
    if grad and w.shape[0] == 1 and B > 1 and coeffs.requires_grad:
        nz = None  # a shared identity's batch with gradients: the plain dense form
    else:
        nz = nonzero_columns(coeffs)
    if nz is None or not grad:
        return _personal_forward(coeffs, mean, w, rows, nz)
    return _PersonalProduct.apply(coeffs, mean, w, rows, nz)


class PersonalBasis(nn.Module):
    """Personalised deltas on M vertices: mean + sum_c w_c(beta) components_c (D deltas).

    The components are kept as ``rows`` (D, C, K), each basis row's C components together
    (the file's (C, D, M, 3) permuted once at load: see :func:`_personal_forward`);
    :attr:`components` is the (C, D, K) view of them."""

    def __init__(self, arrays: dict[str, np.ndarray], prefix: str):
        super().__init__()
        t = lambda k: torch.as_tensor(arrays[f"{prefix}_{k}"])
        self.register_buffer("vertices", t("pca_vertices").long())
        mean, comps = t("pca_mean").float(), t("pca_components").float()
        self.register_buffer("mean", mean.reshape(mean.shape[0], -1))  # (D, 3M)
        comps = comps.reshape(comps.shape[0], comps.shape[1], -1)  # (C, D, 3M)
        self.register_buffer("rows", comps.transpose(0, 1).contiguous())  # (D, C, 3M)
        self.mlp = MLP(*(t(f"mlp_{k}").float() for k in ("w0", "b0", "w1", "b1", "w2", "b2")))

    @property
    def components(self) -> torch.Tensor:
        """(C, D, 3M): the components as in the file (a view of :attr:`rows`)."""
        return self.rows.transpose(0, 1)

    def apply(self, coeffs: torch.Tensor, w: torch.Tensor, mean: torch.Tensor | None = None
              ) -> torch.Tensor:
        """Personal part of coeffs @ basis. coeffs: (B, D), w: (B or 1, C) from :attr:`mlp`
        -> (B, M, 3) metres; ``mean`` (D, 3M) replaces the stored mean (generic rows folded
        in)."""
        out = personal_product(coeffs, self.mean if mean is None else mean, w, self.components)
        return out.reshape(coeffs.shape[0], -1, 3)

    def bias_basis(self, mean: torch.Tensor | None = None) -> torch.Tensor:
        """(D, 3M): ``mean + b2 @ components``, the basis of every identity whose MLP's
        second hidden layer is all zero (:meth:`MLP.weights`); ``mean`` as in :meth:`apply`."""
        mean = self.mean if mean is None else mean
        return mean + torch.matmul(self.mlp.b2.to(mean.dtype), self.rows)

    def basis(self, beta: torch.Tensor) -> torch.Tensor:
        """The personal deltas themselves for one identity. beta: (1, S) -> (D, M, 3)."""
        return (self.mean + torch.matmul(self.mlp(beta)[0], self.rows)).reshape(
            self.rows.shape[0], -1, 3)


class FlexBlock(nn.Module):
    """The flexion block of a format-5 model file (:mod:`hack_render.geometry.flex_block`)
    as buffers, and its offsets."""

    def __init__(self, arrays: dict):
        super().__init__()
        basis = torch.as_tensor(np.asarray(arrays["flex_basis"], np.float32))
        self.num_hats, self.num_terms = basis.shape[:2]
        self.register_buffer("vertices", torch.as_tensor(np.asarray(arrays["flex_vertices"],
                                                                    np.int64)))
        # (H, 1 + S_f, 3M): each hat's rows contiguous, so an active hat is one slice
        self.register_buffer("basis", basis.reshape(self.num_hats, self.num_terms, -1).contiguous())
        self.register_buffer("knots", torch.deg2rad(torch.as_tensor(
            np.asarray(arrays["flex_knots_deg"], np.float32))))
        self.knots_deg = [float(k) for k in np.asarray(arrays["flex_knots_deg"])]
        self.width = math.radians(float(arrays["flex_width_deg"]))
        self.purity = math.radians(float(arrays["flex_purity_deg"]))
        self.coherence = float(arrays["flex_coherence"])

    def weights(self, rot: torch.Tensor, net: torch.Tensor | None = None) -> torch.Tensor:
        """(B, H) from the joints' local rotations (B, K, 3, 3), the root left out (``net``:
        their product, where the caller has it)."""
        return flex_weights(rot, self.knots.to(rot.dtype), self.width, self.purity,
                            self.coherence, net)

    def identity_rows(self, beta: torch.Tensor, hats: torch.Tensor | None = None) -> torch.Tensor:
        """(B, A, 3M): hats ``hats`` (A,) (default: all) of identities beta (B, s),
        ``B_h0 + sum_s beta_s B_hs`` (betas past S_f ignored, missing ones zero)."""
        rows = self.basis if hats is None else self.basis.index_select(0, hats)
        s = min(beta.shape[1], self.num_terms - 1)
        coef = torch.cat([beta.new_ones(beta.shape[0], 1), beta[:, :s]], 1)
        return torch.einsum("bt,atk->bak", coef, rows[:, :1 + s])

    def offsets(self, beta: torch.Tensor, rot: torch.Tensor,
                rows: torch.Tensor | None = None,
                net: torch.Tensor | None = None) -> torch.Tensor | None:
        """(B, M, 3) rest-space offsets for identities beta (B or 1, s) and the joints'
        local rotations rot (B, K, 3, 3) (or, ``rows``, one identity's
        :meth:`identity_rows` (1, H, 3M) for every hat); None when no hat is active (at
        rest, or outside the knots' reach). Reads only the active hats' rows. ``net``: the
        joints' net rotation (B, 3, 3), where the caller has it."""
        w = self.weights(rot, net)
        active = torch.nonzero(w.detach().amax(0) > 0).flatten()
        if len(active) == 0:
            return None
        w = w.index_select(1, active)
        if rows is not None:
            return (w @ rows[0].index_select(0, active)).view(w.shape[0], -1, 3)
        rows = self.identity_rows(beta, active)  # (B or 1, A, 3M)
        return torch.einsum("ba,bak->bk", w, rows.expand(w.shape[0], -1, -1)).view(
            w.shape[0], -1, 3)


def _skin_rows(v: torch.Tensor, weights: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """LBS of some vertices, as :func:`hack_render.geometry.lbs.skin` (the same blend of
    ``rel - I``), with the per-vertex 3x4 product written out elementwise (a batched 3x3 @
    3x1 matmul per vertex is slow). v: (B, M, 3), weights (M, K), rel (B, K, 4, 4)."""
    d = skin_blend(weights, rel)
    return affine_columns(v, d, v + d[..., 3])


def skin_blend(weights: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
    """The blended ``rel - I`` of :func:`_skin_rows`: (M, K), (B, K, 4, 4) or its top rows
    (B, K, 3, 4) -> (B, M, 3, 4)."""
    B, K = rel.shape[:2]
    eye = torch.eye(4, dtype=rel.dtype, device=rel.device)[:3]
    return torch.matmul(weights, (rel[..., :3, :] - eye).reshape(B, K, 12)).view(B, -1, 3, 4)


def affine_columns(v: torch.Tensor, m: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """bias + m[..., :3] v per point, as multiply-adds of v's three columns (a 3-wide
    matmul, or a broadcast product and a sum, is 1.5-2x slower on the CPU). v: (B, M, 3),
    m: (B, M or 1, 3, >= 3), bias broadcastable to (B, M, 3) -> a new (B, M, 3) tensor."""
    out = torch.addcmul(bias, v[..., :1], m[..., 0])
    out.addcmul_(v[..., 1:2], m[..., 1])
    return out.addcmul_(v[..., 2:], m[..., 2])


#: points per row of :func:`_rigid_points`'s block product, tried in this order for one
#: that divides the number of points (else the first, and the rest by column multiply-adds):
#: 0.06-0.09 ms for the default model's 26.7k vertices (k = 7) at B = 1 on one CPU thread,
#: vs 0.2 ms for three column multiply-adds or one (N, 3) x (3, 3) product; 16 and 32 slower
_RIGID_BLOCKS = (4, 8, 6, 5, 7)


def rigid_block(n: int) -> int:
    """Points per row of the block product for n points (:data:`_RIGID_BLOCKS`)."""
    return next((k for k in _RIGID_BLOCKS if n % k == 0), _RIGID_BLOCKS[0])


def _rigid_points(v: torch.Tensor, a: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
    """Every point moved by one rigid transform per batch row: ``a[:, :, :3] v + a[:, :, 3]
    + transl``. v: (B, N, 3), a: (B, 3, 4), transl (B, 3) -> a new (B, N, 3) tensor.

    A (3, 3) product per point is too thin for the CPU's matrix kernels, so the points go
    k to a row (:func:`rigid_block`): (B, N / k, 3k) x the block-diagonal (3k, 3k) matrix
    of k copies of the rotation's transpose (the few points past a multiple of k by column
    multiply-adds). Differentiable in all three."""
    return rigid_apply(v, rigid_operator(a, transl, rigid_block(v.shape[1])))


def rigid_operator(a: torch.Tensor, transl: torch.Tensor, k: int) -> tuple:
    """The parts of :func:`_rigid_points` that do not depend on the points: (a, t, the
    block-diagonal matrices (B, 3k, 3k), their bias rows (B, 1, 3k))."""
    B = a.shape[0]
    rt = a[..., :3].transpose(1, 2)  # (B, 3, 3): row-vector points times R^T
    t = a[..., 3] + transl  # (B, 3)
    eye = torch.eye(k, dtype=a.dtype, device=a.device)
    blocks = (eye[None, :, None, :, None] * rt[:, None, :, None, :]).reshape(B, 3 * k, 3 * k)
    return a, t, blocks, t.repeat(1, k)[:, None]


def rigid_apply(v: torch.Tensor, op: tuple) -> torch.Tensor:
    """:func:`_rigid_points` with its :func:`rigid_operator`."""
    a, t, blocks, bias = op
    B, N, _ = v.shape
    k = blocks.shape[1] // 3
    n0 = N - N % k
    out = torch.baddbmm(bias, v[:, :n0].reshape(B, n0 // k, 3 * k), blocks).view(B, n0, 3)
    if n0 == N:
        return out
    tail = affine_columns(v[:, n0:], a[:, None], t[:, None])
    return torch.cat([out, tail], 1)
