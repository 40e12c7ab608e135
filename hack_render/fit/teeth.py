"""The teeth's fixed pieces for the fit: the incisors' tips the mouth's stage reads, and
the upper teeth's placement under the upper lip, which the model does not carry.

The model's teeth are rigid with the skull (the upper) and the jaw (the lower), placed
as ICT's mean head places them: how much of the upper incisors shows under the upper lip
is the identity modes' (about 1.3 mm, one standard deviation over all 100 modes,
between the upper tips and the lip's midline), while people differ by several
millimetres (obama_speech's photo shows his upper teeth to 40 % of the open mouth's
height, the fitted model 2 px of them). The placement is a drop of the upper teeth
(their vertices ``jawOpen`` does not move), metres along the head's rest -y (positive:
lower, more tooth under the lip), within :data:`TEETH_LIMIT`; on a posed head it is carried
by the rigid (Kabsch) fit of those vertices' rest positions to their posed ones, as
``gaze.py`` carries the eyeballs' turn. Only the upper teeth move: the gums, lips and jaw
stay (the teeth reach about 29 mm up into the gums, so no seam opens within the limit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hack_render.geometry.rigid import kabsch

#: The jaw and lip shapes the mouth's stage fits; a model without them has no rig.
SHAPES = ("jawOpen", "mouthClose", "mouthLowerDown_L", "mouthLowerDown_R",
          "mouthUpperUp_L", "mouthUpperUp_R")
#: The model's teeth tips: vertices within this of the midline (metres), in front (within
#: FRONT of the front-most), and within TIP of the lowest (upper) / highest (lower).
MID_X, FRONT, TIP = 0.008, 0.004, 0.0008
#: The upper teeth's drop's range, metres (either way).
TEETH_LIMIT = 0.003
#: How many of the upper teeth's vertices the posed frame is fitted to (evenly spread).
FRAME_POINTS = 64


@dataclass(frozen=True)
class TeethRig:
    """The model's upper and lower incisors' tips (vertex ids), the shapes' ids, and the
    upper teeth's vertices (``upper_set``: the teeth ``jawOpen`` does not move)."""

    upper: np.ndarray
    lower: np.ndarray
    psi: np.ndarray
    upper_set: np.ndarray


_RIGS: dict = {}


def teeth_rig(model) -> TeethRig | None:
    """The teeth's tips of ``model`` (the ``teeth`` group; the lower teeth are those
    ``jawOpen`` moves), or None where it has no teeth or shapes; cached per model."""
    key = id(model)
    if key not in _RIGS:
        _RIGS[key] = _build_rig(model)
    return _RIGS[key]


def _build_rig(model) -> TeethRig | None:
    names = list(model.expression_names)
    if "teeth" not in model.group_names or not all(s in names for s in SHAPES):
        return None
    teeth = torch.nonzero(model.vertex_group == model.group_names.index("teeth")).flatten()
    n = model.num_vertices
    jaw = model.expr_shape_basis[names.index("jawOpen")].view(n, 3)[teeth]
    moved = jaw.abs().amax(1) > 1e-6
    rest = model.template[teeth]
    out = []
    for sel, sign in ((~moved, 1.0), (moved, -1.0)):  # upper: lowest; lower: highest
        p, ids = rest[sel], teeth[sel]
        if not len(ids):
            return None
        near = (p[:, 0].abs() < MID_X) & (p[:, 2] > p[:, 2].max() - FRONT)
        y = sign * p[near, 1]
        out.append(ids[near][y < y.min() + TIP].numpy())
    return TeethRig(out[0], out[1], np.array([names.index(s) for s in SHAPES]),
                    teeth[~moved].numpy())


def apply_teeth(rig: TeethRig | None, vertices: torch.Tensor, rest: torch.Tensor,
                drop: torch.Tensor) -> torch.Tensor:
    """``vertices`` (N, 3) with the upper teeth lowered by ``drop`` (metres, (1,) or a
    scalar; the module's docstring), clamped to :data:`TEETH_LIMIT`; differentiable in
    ``drop`` and ``vertices`` (the skull's frame is held: found without gradients)."""
    if rig is None:
        return vertices
    ids = rig.upper_set
    pick = ids[np.linspace(0, len(ids) - 1, min(FRAME_POINTS, len(ids))).astype(int)]
    r, _ = kabsch(rest[pick].detach().double().numpy(), vertices[pick].detach().double().numpy())
    down = torch.as_tensor(-r[:, 1], dtype=vertices.dtype)   # the rest -y, posed
    d = drop.reshape(()).to(vertices.dtype).clamp(-TEETH_LIMIT, TEETH_LIMIT)
    idx = torch.as_tensor(ids)
    return vertices.index_add(0, idx, (d * down).expand(len(ids), 3))
