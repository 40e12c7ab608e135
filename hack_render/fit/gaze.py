"""The eyes' fixed pieces for the fit: each eye's lid margin (the skin's boundary loop
around the eye, in order, with its two corners and which side is the upper lid), its
eyeball's vertices and shell, the expression shapes that close or open its lids, and the
eyeballs' gaze: a rotation of each eyeball about its centre, which the model's
expressions do not carry (ICT's ``eyeLook*`` shapes move the lids, not the eyeballs).

The gaze is (yaw, pitch), radians, shared by both eyes (no vergence): the eye's forward
axis turned towards the subject's left (+x at rest) by yaw and up (+y) by pitch, in the
head's rest frame; on a posed head the rotation is carried by the rigid (Kabsch) fit of
each eyeball's rest vertices to its posed ones, about the posed shell's sphere centre
(``render.parts`` finds the eye's centre the same way). Only the eyeball's vertices move
(its sclera, iris and pupil): the lids, the lacrimal film and the lashes stay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hack_render.geometry.rigid import kabsch
from hack_render.render.parts import boundary_loops

#: The expression shapes fitted to the lids' opening, per eye (``_L`` / ``_R`` added):
#: the upper lid down (blink), the lower lid up (squint), the upper lid up (wide).
LID_SHAPES = ("eyeBlink", "eyeSquint", "eyeWide")
#: The gaze's range, radians, per component (yaw, pitch).
GAZE_LIMIT = np.radians(30.0)


@dataclass(frozen=True)
class Eye:
    """One eye of the model: ``side`` ("L": the subject's left, +x; "R"), the lid
    margin's vertex ids in loop order (``loop``), the two corners' positions in it
    (``corners``: outer, inner), ``upper`` the loop positions of the upper lid between
    them, ``lower`` those of the lower lid, the eyeball's vertices (``ball``), its shell's
    (``shell``, the sclera's: the sphere fit), the rest distance from the shell's centre
    to its front (``apex``, metres) and the lid shapes' expression ids (``psi``)."""

    side: str
    loop: np.ndarray
    corners: tuple[int, int]
    upper: np.ndarray
    lower: np.ndarray
    ball: np.ndarray
    shell: np.ndarray
    apex: float
    psi: np.ndarray


def sphere_centre(v: np.ndarray) -> np.ndarray:
    """The least-squares sphere centre of points (n, 3)."""
    sol = np.linalg.lstsq(np.c_[2 * v, np.ones(len(v))], (v ** 2).sum(1), rcond=None)[0]
    return sol[:3]


_RIGS: dict = {}


def eye_rig(model) -> list[Eye]:
    """The model's two eyes (:class:`Eye`; the subject's left first), cached per model; []
    where the model has no eyeballs, eyelid loops or lid shapes."""
    key = id(model)
    if key not in _RIGS:
        _RIGS[key] = _build_rig(model)
    return _RIGS[key]


def _build_rig(model) -> list[Eye]:
    groups = list(model.group_names)
    names = [str(n) for n in model.expression_names]
    if "face" not in groups:
        return []
    g = model.vertex_group.numpy()
    faces = model.faces.numpy()
    rest = model.template.numpy().astype(np.float64)
    mats = list(model.material_names)
    skin = (g[faces] == groups.index("face")).all(1)
    loops = boundary_loops(faces[skin])
    out = []
    for side, word in (("L", "left"), ("R", "right")):
        ball_name, shell_name = f"eyeball_{word}", f"M_Sclera{word.capitalize()}"
        shapes = [f"{s}_{side}" for s in LID_SHAPES]
        if ball_name not in groups or shell_name not in mats or not all(
                s in names for s in shapes):
            return []
        ball = np.flatnonzero(g == groups.index(ball_name))
        shell = np.unique(faces[model.face_material.numpy() == mats.index(shell_name)])
        c = sphere_centre(rest[shell])
        front = rest[shell][np.argmax(rest[shell][:, 2])]
        loop = min(loops, key=lambda q: float(np.linalg.norm(rest[q].mean(0) - c)))
        loop = np.asarray(loop)
        if np.linalg.norm(rest[loop].mean(0) - c) > 0.03:
            return []
        x = rest[loop, 0]
        outer = int(np.argmax(np.abs(x)))
        inner = int(np.argmin(np.abs(x)))
        # the two chains between the corners; the upper lid's is the higher one
        n = len(loop)
        a = [(outer + k) % n for k in range(1, (inner - outer) % n)]
        b = [(inner + k) % n for k in range(1, (outer - inner) % n)]
        up, lo = (a, b) if rest[loop[a], 1].mean() > rest[loop[b], 1].mean() else (b, a)
        out.append(Eye(side, loop, (outer, inner), np.asarray(up), np.asarray(lo), ball, shell,
                       float(np.linalg.norm(front - c)),
                       np.asarray([names.index(s) for s in shapes])))
    return out


def gaze_rotation(gaze: torch.Tensor) -> torch.Tensor:
    """(3, 3) the rotation taking the rest forward axis +z to the direction of ``gaze``
    (yaw, pitch): Ry(yaw) Rx(-pitch)."""
    yaw, pitch = gaze[0], gaze[1]
    cy, sy, cp, sp = torch.cos(yaw), torch.sin(yaw), torch.cos(pitch), torch.sin(pitch)
    one, zero = torch.ones_like(cy), torch.zeros_like(cy)
    ry = torch.stack([torch.stack([cy, zero, sy]), torch.stack([zero, one, zero]),
                      torch.stack([-sy, zero, cy])])
    rx = torch.stack([torch.stack([one, zero, zero]), torch.stack([zero, cp, sp]),
                      torch.stack([zero, -sp, cp])])
    return ry @ rx


def eye_frames(eyes: list[Eye], vertices: np.ndarray, rest: np.ndarray
               ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per eye (posed centre (3,), rotation rest -> posed (3, 3)) from posed and rest
    vertices (N, 3) (the model's output: ``vertices`` and ``rest_vertices``)."""
    out = []
    for e in eyes:
        r, _ = kabsch(rest[e.ball].astype(np.float64), vertices[e.ball].astype(np.float64))
        out.append((sphere_centre(vertices[e.shell].astype(np.float64)), r))
    return out


def apply_gaze(eyes: list[Eye], vertices: torch.Tensor, rest: torch.Tensor,
               gaze: torch.Tensor) -> torch.Tensor:
    """``vertices`` (N, 3) with each eyeball turned by ``gaze`` (yaw, pitch) about its
    centre (the module's docstring); differentiable in ``gaze`` and ``vertices`` (the
    eye's frame is held: found without gradients)."""
    if not eyes:
        return vertices
    frames = eye_frames(eyes, vertices.detach().double().numpy(),
                        rest.detach().double().numpy())
    g = gaze_rotation(gaze.to(vertices.dtype))
    out = vertices
    for e, (c, r) in zip(eyes, frames):
        rt = torch.as_tensor(r, dtype=vertices.dtype)
        ct = torch.as_tensor(c, dtype=vertices.dtype)
        turn = rt @ g @ rt.T
        idx = torch.as_tensor(e.ball)
        moved = (vertices[idx] - ct) @ turn.T + ct
        out = out.index_copy(0, idx, moved)
    return out


def iris_centres(eyes: list[Eye], vertices: torch.Tensor, rest: torch.Tensor,
                 gaze: torch.Tensor | None) -> torch.Tensor:
    """(2, 3) each eye's front (its shell's apex: where the pupil is seen) on the posed
    (and turned) eyeball: the centre plus ``apex`` along the eye's forward axis (the
    rest +z carried by its frame, turned by the gaze)."""
    frames = eye_frames(eyes, vertices.detach().double().numpy(),
                        rest.detach().double().numpy())
    z = torch.tensor([0.0, 0.0, 1.0], dtype=vertices.dtype)
    if gaze is not None:
        z = gaze_rotation(gaze.to(vertices.dtype)) @ z
    pts = []
    for e, (c, r) in zip(eyes, frames):
        rt = torch.as_tensor(r, dtype=vertices.dtype)
        # the centre follows the vertices (the lid shapes and the pose move the head)
        ct = vertices[torch.as_tensor(e.shell)].mean(0) - (
            vertices[torch.as_tensor(e.shell)].mean(0).detach()
            - torch.as_tensor(c, dtype=vertices.dtype))
        pts.append(ct + e.apex * (rt @ z))
    return torch.stack(pts)
