"""Posing one mesh with NumPy alone: G(beta, psi, theta, eta, tau) for a single parameter
set, without importing torch.

`hack-render render` poses one mesh per call, and importing torch costs about 1 CPU s of
the ~3 CPU s a new pose took (docs/render.md, "Fixed cost per call"). This module reads the
model file's arrays (mapped from the unpacked cache of
:mod:`hack_render.geometry.model_file`) and evaluates the same model as
:meth:`hack_render.geometry.model.HackModel.forward`:

    T = T_bar + B_S(beta) + B_E(psi; E_beta) + B_P(theta; P_beta) + F(beta, theta)
        + eta L(beta, tau)
    G = LBS(T, J(beta), theta, W)

in float32 like the torch model, for one row. It takes the same inputs from a checked
parameter mapping (:func:`posed_vertices`; :func:`hack_render.geometry.params.forward_inputs`),
applies ``--limits`` through :mod:`hack_render.geometry.limits`, and prints the same
warnings. It is not differentiable: fitting, batches and gradients use :class:`HackModel`
(:func:`hack_render.geometry.loading.posed_model` poses one mesh with it, as
:func:`posed_vertices` does without).
``tests/test_posing.py`` holds the two equal (to 2e-6 m on vertices) over random
identities, expressions, eta, tau and joint poses within and beyond the limits.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hack_render import boundary
from hack_render.errors import HackError
from hack_render.geometry import np_rotations
from hack_render.geometry.anatomy import ETA_DEFAULT, NUM_JOINTS
from hack_render.geometry.expressions import expression_weights
from hack_render.geometry.flex_block import flex_offsets_np
from hack_render.geometry.limits import apply_limit_policy
from hack_render.geometry.model_file import default_model_path, load_model_file
from hack_render.geometry.params import forward_inputs, gather_params


class PosingModel:
    """The arrays of a model file that posing reads, as NumPy (float32), and the
    attributes :meth:`hack_render.render.parts.Topology.from_model` takes."""

    def __init__(self, arrays: dict[str, np.ndarray]):
        a = arrays
        self.arrays = a
        self.template = a["template_vertices"]
        self.num_vertices = self.template.shape[0]
        self.faces, self.uvs, self.uv_faces = a["faces"], a["uvs"], a["uv_faces"]
        self.face_material = a["face_material"]
        self.material_names = tuple(str(s) for s in a["material_names"])
        self.expression_names = tuple(str(s) for s in a["expression_names"])
        self.au_names = tuple(str(s) for s in a["au_names"])
        self.num_shape = a["shape_components"].shape[0]
        self.num_expressions = len(self.expression_names)
        self.parents = tuple(int(p) for p in a["joint_parents"])
        self.has_larynx = "larynx_maps" in a
        if len(self.parents) != NUM_JOINTS:
            raise HackError(f"model: posing without torch takes {NUM_JOINTS} joints, found "
                            f"{len(self.parents)}.")

    @classmethod
    def from_file(cls, path: str | Path) -> PosingModel:
        return cls(load_model_file(path)[0])

    def expression_vector(self, spec) -> np.ndarray:
        return expression_weights(spec, self.expression_names, self.au_names,
                                  np.asarray(self.arrays["au_matrix"], dtype=np.float32))

    def inputs(self, params: dict[str, Any]) -> dict[str, np.ndarray]:
        """One row of forward inputs from a checked parameter mapping (float32):
        :func:`forward_inputs`, as the torch path's."""
        return forward_inputs(self, params)

    # ----------------------------------------------------------------------- forward
    def vertices(self, beta=None, psi=None, theta=None, global_orient=None, transl=None,
                 eta=None, tau=None) -> np.ndarray:
        """Posed vertices (N, 3) float32 of one parameter set (missing inputs: zeros, eta
        = 1), as ``HackModel.forward(...).vertices[0]``."""
        a, f32 = self.arrays, np.float32
        n, s_all = self.num_vertices, self.num_shape
        beta_full = np.zeros(s_all, dtype=f32)
        if beta is not None:
            beta_full[:len(beta)] = beta
        psi = np.zeros(self.num_expressions, f32) if psi is None else np.asarray(psi, f32)
        theta = np.zeros((NUM_JOINTS, 3), f32) if theta is None else np.asarray(theta, f32)
        orient = np.zeros(3, f32) if global_orient is None else np.asarray(global_orient, f32)
        transl = np.zeros(3, f32) if transl is None else np.asarray(transl, f32)
        eta = f32(ETA_DEFAULT if eta is None else eta)
        tau = f32(0.0 if tau is None else tau)

        used = np.flatnonzero(beta_full)  # betas past the given ones are zero: not read
        shaped = self.template.reshape(-1).astype(f32)
        if len(used):
            comps = a["shape_components"]
            comps = comps if len(used) == s_all else comps[used]
            shaped = shaped + (beta_full[used] * a["shape_std"][used]) @ comps.reshape(len(used), -1)
        rest = shaped + psi @ a["expression_basis"].reshape(self.num_expressions, -1)
        rest = rest.reshape(n, 3)
        rot = np_rotations.axis_angle_to_matrix(np.concatenate([orient[None], theta])).astype(f32)
        feat = rot[1:] - np.eye(3, dtype=f32)  # (8, 3, 3) pose feature R - I
        if "pose_gate_deg" in a:  # format 3: gated by each joint's angle (lbs.pose_gate)
            s = 3.0 - np.trace(rot[1:], axis1=1, axis2=2)
            if "pose_gate_chain" in a:  # format 4: and by the chain's net rotation
                r = rot[1:]
                net = 0.5 * np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                                      r[:, 1, 0] - r[:, 0, 1]], -1).sum(0)
                s = s + float(a["pose_gate_chain"]) * float(net @ net)
            feat = feat * (s * s / (s * s + np.deg2rad(float(a["pose_gate_deg"])) ** 4))[:, None, None]
        feat = feat.reshape(-1).astype(f32)  # (72,)
        if "pose_basis" in a:
            rest += (feat @ a["pose_basis"].reshape(feat.shape[0], -1)).reshape(n, 3)
        for prefix, coeffs in (("expr", psi), ("pose", feat)):
            if f"{prefix}_pca_vertices" in a:
                rest[a[f"{prefix}_pca_vertices"]] += self._personal(prefix, coeffs, beta_full)
        if "flex_basis" in a:  # format 5: the flexion block
            d = flex_offsets_np(a, beta_full, theta)
            if d is not None:
                rest[a["flex_vertices"]] += d
        if self.has_larynx:
            rest[a["larynx_vertices"]] += self._larynx(beta_full, eta, tau)
        joints = a["joint_regressor"] @ shaped.reshape(n, 3)  # J(beta): (K, 3)
        rel = _rigid_transforms(rot, np.concatenate([joints[:1], joints]),
                                (-1,) + tuple(p + 1 for p in self.parents))
        return _skin(rest, a["skinning_weights"], rel) + transl

    def _personal(self, prefix: str, coeffs: np.ndarray, beta: np.ndarray) -> np.ndarray:
        """coeffs @ (mean + sum_c w_c(beta) components_c) on the basis's vertices: (M, 3)."""
        a = self.arrays
        x = beta[:a[f"{prefix}_mlp_w0"].shape[1]]
        x = np.pad(x, (0, a[f"{prefix}_mlp_w0"].shape[1] - x.shape[0]))
        x = np.maximum(a[f"{prefix}_mlp_w0"] @ x + a[f"{prefix}_mlp_b0"], 0)
        x = np.maximum(a[f"{prefix}_mlp_w1"] @ x + a[f"{prefix}_mlp_b1"], 0)
        w = a[f"{prefix}_mlp_w2"] @ x + a[f"{prefix}_mlp_b2"]  # (C,)
        mean, comps = a[f"{prefix}_pca_mean"], a[f"{prefix}_pca_components"]
        C, D = comps.shape[:2]
        out = coeffs @ mean.reshape(D, -1) + w @ (coeffs @ comps.reshape(C, D, -1))
        return out.reshape(-1, 3)

    def _larynx(self, beta: np.ndarray, eta, tau) -> np.ndarray:
        """eta L(beta, tau) at the larynx vertices: (M, 3), bilinear and zero outside the
        maps as :func:`hack_render.geometry.larynx.sample_displacement`."""
        a = self.arrays
        A = a["larynx_coef_matrix"]
        s = min(beta.shape[0], A.shape[1])
        c = A[:, :s] @ beta[:s] + a["larynx_coef_offset"]
        maps = np.einsum("l,lchw->chw", c, a["larynx_maps"])  # (3, H, W)
        chart = (a["larynx_vertex_uv"] if "larynx_vertex_uv" in a
                 else a["vertex_uv"][a["larynx_vertices"]])
        u0, v0, u1, v1 = (float(x) for x in a["larynx_uv_bounds"])
        u = chart[:, 0]
        v = chart[:, 1] + tau * np.float32(a["larynx_v_per_metre"])
        _, H, W = maps.shape
        # grid_sample(align_corners=False): pixel coordinates of the normalised grid
        gx, gy = 2 * (u - u0) / (u1 - u0) - 1, 1 - 2 * (v - v0) / (v1 - v0)
        x, y = ((gx + 1) * W - 1) / 2, ((gy + 1) * H - 1) / 2
        x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
        out = np.zeros((len(u), 3), dtype=maps.dtype)
        for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            xi, yi = x0 + dx, y0 + dy
            wgt = (1 - np.abs(x - xi)) * (1 - np.abs(y - yi))
            ok = (xi >= 0) & (xi < W) & (yi >= 0) & (yi < H)  # zero padding outside
            out[ok] += (wgt[ok, None] * maps[:, yi[ok], xi[ok]].T).astype(maps.dtype)
        return eta * out


def _rigid_transforms(rot: np.ndarray, nodes: np.ndarray, parents: tuple[int, ...]
                      ) -> np.ndarray:
    """Forward kinematics of the chain as :func:`hack_render.geometry.lbs.rigid_transforms`:
    (K, 3, 3) local rotations, (K, 3) rest nodes -> (K, 4, 4) rest-to-posed transforms."""
    K = nodes.shape[0]
    local = np.zeros((K, 4, 4), dtype=rot.dtype)
    local[:, :3, :3] = rot
    local[:, :3, 3] = nodes - np.where(np.array(parents)[:, None] >= 0,
                                       nodes[[max(p, 0) for p in parents]], 0)
    local[:, 3, 3] = 1
    world = [local[0]]
    for k in range(1, K):
        world.append(world[parents[k]] @ local[k])
    rel = np.stack(world)
    rel[:, :3, 3] = rel[:, :3, 3] - np.einsum("kij,kj->ki", rel[:, :3, :3], nodes)
    return rel


def _skin(rest: np.ndarray, weights: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """LBS as :func:`hack_render.geometry.lbs.skin` (the blend of ``rel - I``)."""
    K = rel.shape[0]
    d = (weights @ (rel[:, :3, :] - np.eye(4, dtype=rel.dtype)[:3]).reshape(K, 12)).reshape(-1, 3, 4)
    return rest + np.einsum("nij,nj->ni", d[..., :3], rest) + d[..., 3]


def posed_vertices(params_file, beta, expression, head_rotation, eta, tau, limits,
                   model_path) -> tuple[PosingModel, np.ndarray]:
    """The model and its posed vertices (N, 3) from a parameter file and flags, as
    :func:`hack_render.geometry.loading.posed_model` gives them, without torch."""
    if model_path is not None:
        boundary.input_file(model_path, "--model", (".npz",), "model file")
    model = PosingModel.from_file(model_path if model_path is not None else default_model_path())
    p = gather_params(params_file, beta, expression, head_rotation, eta, tau)
    kw = apply_limit_policy(model.inputs(p), limits, p.get("head_rotation_deg"))
    return model, model.vertices(**kw)
