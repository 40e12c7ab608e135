"""Building the default HACK model file from ICT-FaceKit (MIT licence, USC ICT 2020).

Accepts either the development data layout (``ict_facekit.npz`` + ``generic_neutral_mesh.obj`` +
``vertex_indices.json``) or the original ICT-FaceKit ``FaceXModel/`` folder of OBJs
(``generic_neutral_mesh.obj``, ``identity000.obj`` ..., one OBJ per expression shape named
after it, and ``vertex_indices.json``), and writes one validated ``.npz`` (see
:mod:`hack_render.geometry.model_file`).

Provenance of each component is written into the file's metadata: the template, shape
space and expressions are captured data (ICT-FaceKit); the skeleton and skinning weights are
derived from anatomical priors; personalised blendshapes, pose blendshapes and the larynx
basis are not yet learned in this version (model file v1, components absent).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy import sparse

from hack_render.errors import HackError
from hack_render.geometry.obj_io import read_obj
from hack_render.geometry.skeleton import JOINT_NAMES, PARENTS, rotation_limits_deg
from hack_render.learn.skeleton_fit import (
    DEPTH_FRACTION,
    affine_regressor,
    midline_profiles,
    place_joints,
)

CM = 0.01  # ICT-FaceKit is in centimetres

# ICT geometry groups, inclusive vertex ranges (shared DATA.md).
GROUPS = (
    ("face", 0, 9408), ("head_and_neck", 9409, 11247), ("mouth_socket", 11248, 13293),
    ("eye_socket_left", 13294, 13677), ("eye_socket_right", 13678, 14061),
    ("gums_and_tongue", 14062, 17038), ("teeth", 17039, 21450),
    ("eyeball_left", 21451, 23020), ("eyeball_right", 23021, 24590),
    ("lacrimal_fluid_left", 24591, 24794), ("lacrimal_fluid_right", 24795, 24998),
    ("eye_blend_left", 24999, 25022), ("eye_blend_right", 25023, 25046),
    ("eye_occlusion_left", 25047, 25198), ("eye_occlusion_right", 25199, 25350),
    ("eyelashes_left", 25351, 26034), ("eyelashes_right", 26035, 26718),
)
SKIN_LAST = 11247
CHIN_LANDMARK = 8  # Multi-PIE index of the chin

# FACS action units -> ICT/ARKit shapes. Names and definitions: Ekman, Friesen & Hager, *Facial
# Action Coding System* (2002); ARKit shapes: Apple's ARFaceAnchor.BlendShapeLocation
# documentation (ICT-FaceKit uses the same names with _L/_R, left = the subject's left).
# Every AU is a non-negative sum of shapes, so AU30 and the gaze AUs are split by direction.
# Checked entry by entry against the FACS definitions (issue 21); the earlier table (DATA.md)
# had AU10 on mouthShrugUpper, AU11 on mouthUpperUp, AU27 on jawOpen and no AU26, and AU33 on
# cheekPuff.
AU_TABLE: dict[str, tuple[str, ...]] = {
    "AU1": ("browInnerUp_L", "browInnerUp_R"),      # inner brow raiser
    "AU2": ("browOuterUp_L", "browOuterUp_R"),      # outer brow raiser
    "AU4": ("browDown_L", "browDown_R"),            # brow lowerer
    "AU5": ("eyeWide_L", "eyeWide_R"),              # upper lid raiser
    "AU6": ("cheekSquint_L", "cheekSquint_R"),      # cheek raiser
    "AU7": ("eyeSquint_L", "eyeSquint_R"),          # lid tightener
    "AU9": ("noseSneer_L", "noseSneer_R"),          # nose wrinkler
    "AU10": ("mouthUpperUp_L", "mouthUpperUp_R"),   # upper lip raiser
    "AU12": ("mouthSmile_L", "mouthSmile_R"),       # lip corner puller
    "AU14": ("mouthDimple_L", "mouthDimple_R"),     # dimpler
    "AU15": ("mouthFrown_L", "mouthFrown_R"),       # lip corner depressor
    "AU16": ("mouthLowerDown_L", "mouthLowerDown_R"),  # lower lip depressor
    # chin raiser: pushes the chin boss and lower lip up, and the closed upper lip with it
    # (ARKit splits this "mouth shrug" into its lower- and upper-lip parts)
    "AU17": ("mouthShrugLower", "mouthShrugUpper"),
    "AU18": ("mouthPucker",),                       # lip pucker
    "AU20": ("mouthStretch_L", "mouthStretch_R"),   # lip stretcher (corners pulled sideways)
    "AU22": ("mouthFunnel",),                       # lip funneler
    "AU24": ("mouthPress_L", "mouthPress_R"),       # lip pressor
    "AU26": ("jawOpen",),                           # jaw drop
    "AU28": ("mouthRollLower", "mouthRollUpper"),   # lip suck
    "AU29": ("jawForward",),                        # jaw thrust
    "AU30L": ("jawLeft",), "AU30R": ("jawRight",),  # jaw sideways, to the left / right
    "AU34": ("cheekPuff_L", "cheekPuff_R"),         # cheek puff (AU33 is cheek blow)
    "AU43": ("eyeBlink_L", "eyeBlink_R"),           # eyes closed
    "AU45": ("eyeBlink_L", "eyeBlink_R"),           # blink (a brief AU43)
    "AU61": ("eyeLookOut_L", "eyeLookIn_R"),        # eyes turn left
    "AU62": ("eyeLookIn_L", "eyeLookOut_R"),        # eyes turn right
    "AU63": ("eyeLookUp_L", "eyeLookUp_R"),         # eyes up
    "AU64": ("eyeLookDown_L", "eyeLookDown_R"),     # eyes down
}
# FACS AUs without an ARKit shape (AU11, AU13, AU23, AU25, AU27) are listed, with why, in
# hack_render.geometry.expressions.FACS_WITHOUT_SHAPES, so the expression parser can name them.


def facs_au_table(expression_names) -> tuple[np.ndarray, np.ndarray]:
    """The FACS action-unit table for a set of expression shapes.

    Args:
        expression_names: (E,) the model's expression shape names (ICT/ARKit names).

    Returns:
        (au_names (A,) str, au_matrix (A, E) float32): row a holds 1 for each shape of
        ``AU_TABLE[au_names[a]]``; an AU whose shapes are not all in ``expression_names``
        is left out. Apply to a model file's arrays as
        ``arrays["au_names"], arrays["au_matrix"] = facs_au_table(arrays["expression_names"])``.
    """
    names = [str(n) for n in expression_names]
    rows = [(au, shapes) for au, shapes in AU_TABLE.items() if all(s in names for s in shapes)]
    au = np.zeros((len(rows), len(names)), dtype=np.float32)
    for a, (_, shapes) in enumerate(rows):
        for s in shapes:
            au[a, names.index(s)] = 1.0
    return np.array([r[0] for r in rows]), au


# Window of the neck coordinate s over which each joint's cumulative influence C_k ramps
# from 0 to 1 (see skinning_weights). The lower joints get successively higher bands; c1-c2
# and o-c1 both sit at the level of the skull base, above all neck skin, so the whole neck
# follows them progressively (c1-c2 turns up to 40 degrees: its twist must be spread over
# the neck's full length).
HEAD_MARGIN_M = 0.035  # skin this far above the head cut is rigid with the skull
LATERAL_M = 0.11  # shoulders: skin beyond this |x| (below the jaw) stays with the root
CHEST_DROP_M = 0.05  # chest: skin this far below the c7-t1 joint stays with the root
RAMP_WINDOWS = ((0.0, 0.45), (0.0, 0.55), (0.0, 0.65), (0.0, 0.75), (0.0, 0.85), (0.0, 0.95),
                (0.0, 1.0), (0.0, 1.0))
REGIONS = ("face", "scalp_and_ears", "neck", "chest_and_shoulders", "mouth_interior",
           "eye_socket", "eye", "teeth", "gums_and_tongue", "eyelashes", "eye_helper")


_WHERE = (" ICT-FaceKit is public (MIT licence): get it from github.com/ICT-VGL/ICT-FaceKit "
          "(the FaceXModel/ folder) and pass that folder.")


def load_ict(path: str | Path) -> dict:
    """Read ICT-FaceKit from the development layout (``ict_facekit.npz`` beside the OBJ) or from an original ``FaceXModel`` folder.

    Returns a dict with ``neutral`` (N, 3) cm, ``identity`` (I, N, 3) and ``expressions``
    (E, N, 3) cm deltas, ``expression_names``, ``mesh`` (:class:`ObjMesh`) and ``indices``.
    """
    path = Path(path)
    if not path.is_dir():
        raise HackError(f"--ict {path}: not a folder. Pass the ICT-FaceKit folder (with "
                        "ict_facekit.npz, or the original FaceXModel/ folder of OBJs)." + _WHERE)
    if (path / "FaceXModel").is_dir():
        path = path / "FaceXModel"
    obj = path / "generic_neutral_mesh.obj"
    js = path / "vertex_indices.json"
    for req in (obj, js):
        if not req.is_file():
            raise HackError(f"--ict {path}: missing {req.name}; expected ICT-FaceKit's "
                            "generic_neutral_mesh.obj and vertex_indices.json there." + _WHERE)
    mesh = read_obj(obj)
    indices = json.loads(js.read_text())
    npz = path / "ict_facekit.npz"
    if npz.is_file():
        with np.load(npz) as z:
            neutral = z["neutral"].astype(np.float64)
            identity = z["identity_deltas"].astype(np.float64)
            expressions = z["expression_deltas"].astype(np.float64)
            names = [str(s) for s in z["expression_names"]]
    else:
        neutral = mesh.vertices
        id_files = sorted(path.glob("identity[0-9][0-9][0-9].obj"))
        if not id_files:
            raise HackError(f"--ict {path}: no ict_facekit.npz and no identityNNN.obj files.")
        identity = np.stack([read_obj(f).vertices - neutral for f in id_files])
        names = list(indices["expressions"])
        missing = [n for n in names if not (path / f"{n}.obj").is_file()]
        if missing:
            raise HackError(f"--ict {path}: expression OBJs missing: {missing[:5]}...")
        expressions = np.stack([read_obj(path / f"{n}.obj").vertices - neutral for n in names])
    if len(neutral) != len(mesh.vertices):
        raise HackError(f"--ict {path}: {len(neutral)} vertices in the blendshapes but "
                        f"{len(mesh.vertices)} in generic_neutral_mesh.obj.")
    return {"neutral": neutral, "identity": identity, "expressions": expressions,
            "expression_names": names, "mesh": mesh, "indices": indices}


def shape_pca(identity_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal PCA of identity modes scaled by their std (ICT samples weights ~ N(0, 1)).

    With D (I, 3N) the modes, shapes are D^T b, b ~ N(0, I), so the covariance is
    V S^2 V^T for D = U S V^T: components V^T (orthonormal rows), std S, and
    beta = U^T b ~ N(0, I) again.
    """
    d = identity_m.reshape(len(identity_m), -1)
    _, s, vt = np.linalg.svd(d, full_matrices=False)
    keep = s > s[0] * 1e-6
    return vt[keep].reshape(int(keep.sum()), -1, 3), s[keep]


def averaging_operator(faces: np.ndarray, n: int, v: np.ndarray | None = None) -> sparse.csr_matrix:
    """Row-normalised adjacency (n, n) of a triangle mesh: uniform, or weighted by inverse
    edge length when ``v`` is given (then a harmonic function is linear in arc length along
    a chain, whatever the local mesh density)."""
    i = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2], faces[:, 1], faces[:, 2], faces[:, 0]])
    j = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0], faces[:, 0], faces[:, 1], faces[:, 2]])
    a = sparse.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()
    a.data[:] = 1.0  # duplicates (shared edges) count once
    if v is not None:
        a = a.tocoo()
        a = sparse.csr_matrix((1.0 / np.maximum(np.linalg.norm(v[a.row] - v[a.col], axis=1), 1e-6),
                               (a.row, a.col)), shape=(n, n))
    deg = np.asarray(a.sum(1)).ravel()
    deg[deg == 0] = 1
    return sparse.diags(1 / deg) @ a


def skinning_weights(v: np.ndarray, faces: np.ndarray, joints: np.ndarray,
                     chin_neck: np.ndarray, back_head: np.ndarray, ear_lobe_z: float,
                     smooth_iters: int = 5):
    """Weights (N, 9) over root + 8 joints, and the head-rigid and chest masks.

    * Non-skin parts (mouth, eyes, teeth, gums, lashes) and skin above the head cut (a
      plane along X through the chin-neck angle and the occipital base) move rigidly with
      o-c1; behind the ear lobe the rigid part starts higher, HEAD_MARGIN_M above the cut
      (ramped in over 3 cm of depth), so the nuchal skin below the skull can twist while
      the face, jaw and chin stay rigid.
    * Chest and shoulders (more than CHEST_DROP_M below c7-t1, or lateral beyond
      LATERAL_M) stay with the root.
    * In between, a neck coordinate s (0 on the chest, 1 on the head) minimises the shear
      of a neck twist (:func:`twist_coordinate`). The share of joint k's rotation that a
      vertex follows, C_k = sum_{j >= k} w_j, ramps linearly from 0 to 1 over the window
      RAMP_WINDOWS[k] of s; the windows' ends are non-decreasing in k, so
      w_k = C_k - C_{k+1} >= 0.
    * A few rounds of Laplacian smoothing soften the ramps' ends.
    """
    n = len(v)
    skin = np.arange(n) <= SKIN_LAST
    d = back_head - chin_neck
    normal = np.array([0.0, d[2], -d[1]]) / np.hypot(d[1], d[2])
    if normal[1] < 0:
        normal = -normal
    margin = HEAD_MARGIN_M * np.clip((ear_lobe_z - v[:, 2]) / 0.03, 0, 1)
    head = ((v - chin_neck) @ normal > margin) | ~skin
    lateral = (np.abs(v[:, 0]) > LATERAL_M) & (v[:, 1] < joints[-1, 1] - 0.06)
    chest = skin & ~head & ((v[:, 1] < joints[0, 1] - CHEST_DROP_M) | lateral)
    if not chest.any() or not (head & skin).any():
        raise HackError("skinning weights: the chest or head region is empty on this template "
                        f"(chest {int(chest.sum())}, head skin {int((head & skin).sum())} vertices); "
                        "the template must reach below the neck and above the jaw.")
    s = twist_coordinate(faces, v, one=head, zero=chest, axis_z=joints[6, 2])
    lo, hi = np.asarray(RAMP_WINDOWS).T
    cum = np.clip((s[:, None] - lo) / (hi - lo), 0, 1)  # (N, 8): C_k
    cum = np.concatenate([np.ones((n, 1)), cum, np.zeros((n, 1))], 1)
    w = cum[:, :-1] - cum[:, 1:]  # root, c7-t1, ..., o-c1
    fixed = head | chest
    avg = averaging_operator(faces, n, v)
    w0 = w.copy()
    for _ in range(smooth_iters):
        w = avg @ w
        w[fixed] = w0[fixed]
    w = np.clip(w, 0, None)
    w /= w.sum(1, keepdims=True)
    return w, head, chest


def cotangent_weights(faces: np.ndarray, v: np.ndarray) -> sparse.csr_matrix:
    """Symmetric cotangent edge weights (n, n) of a triangle mesh, negatives clamped to a
    small positive value so the Laplacian stays an M-matrix (maximum principle holds)."""
    n = len(v)
    rows, cols, vals = [], [], []
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        # the angle at corner c is opposite edge (a, b)
        e1, e2 = v[faces[:, a]] - v[faces[:, c]], v[faces[:, b]] - v[faces[:, c]]
        cot = (e1 * e2).sum(1) / np.maximum(np.linalg.norm(np.cross(e1, e2), axis=1), 1e-12)
        rows += [faces[:, a], faces[:, b]]
        cols += [faces[:, b], faces[:, a]]
        vals += [0.5 * cot, 0.5 * cot]
    w = sparse.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n, n)).tocsr()
    w.data = np.maximum(w.data, 1e-3)
    return w


def twist_coordinate(faces: np.ndarray, v: np.ndarray, one: np.ndarray, zero: np.ndarray,
                     axis_z: float) -> np.ndarray:
    """The ramp s (0 on ``zero``, 1 on ``one``) that minimises the shear of a neck twist.

    A twist of angle a applied with weight s(x) displaces skin by a * r * s, r the distance
    from the (vertical) twist axis, so the shear energy is a^2 int r^2 |grad s|^2 dA.
    Its minimiser solves the r^2-weighted Laplace equation, discretised with cotangent
    weights times r^2 at the edge midpoints.
    """
    from scipy.sparse.linalg import spsolve

    n = len(v)
    w = cotangent_weights(faces, v).tocoo()
    mid = 0.5 * (v[w.row] + v[w.col])
    r2 = mid[:, 0] ** 2 + (mid[:, 2] - axis_z) ** 2
    w = sparse.csr_matrix((w.data * (r2 + 1e-4), (w.row, w.col)), shape=(n, n))
    lap = sparse.diags(np.asarray(w.sum(1)).ravel()) - w
    fixed = one | zero
    free = ~fixed & (np.asarray(w.sum(1)).ravel() > 0)
    s = np.where(one, 1.0, 0.0)
    rhs = -lap[free][:, fixed] @ s[fixed]
    s[free] = spsolve(lap[free][:, free].tocsc(), rhs)
    return np.clip(s, 0, 1)


def build_default_model(ict_path: str | Path) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays and metadata of the default model, from an ICT-FaceKit folder."""
    ict = load_ict(ict_path)
    mesh = ict["mesh"]
    v = ict["neutral"] * CM
    n = len(v)
    comps, std = shape_pca(ict["identity"] * CM)
    names = ict["expression_names"]
    landmarks = np.asarray(ict["indices"]["idx_to_landmark_verts"], dtype=np.int32)
    skin_idx = np.arange(SKIN_LAST + 1)
    socket = next((lo, hi) for g, lo, hi in GROUPS if g == "mouth_socket")
    placed = place_joints(v, skin_idx, int(landmarks[CHIN_LANDMARK]),
                          np.arange(socket[0], socket[1] + 1))
    joints = placed["joints"]
    regressor = affine_regressor(v, skin_idx, joints)
    ys, front, back = midline_profiles(v[skin_idx])
    chin_y = v[landmarks[CHIN_LANDMARK], 1]
    y_cn = chin_y - 0.012  # just below the chin-neck angle
    chin_neck = np.array([0.0, y_cn, np.interp(y_cn, ys, np.nan_to_num(front, nan=-1))])
    y_ob = joints[-1, 1] - 0.03  # occipital base, below the o-c1 level at the back
    back_head = np.array([0.0, y_ob, np.interp(y_ob, ys, np.nan_to_num(back, nan=1))])
    weights, head_mask, chest_mask = skinning_weights(v, mesh.faces, joints, chin_neck, back_head,
                                                      float(placed["ear_lobe"][2]))

    group = np.zeros(n, dtype=np.int16)
    for gi, (_, lo, hi) in enumerate(GROUPS):
        group[lo:hi + 1] = gi
    gname = [GROUPS[g][0] for g in group]
    region = np.zeros(n, dtype=np.int16)
    for i in range(n):
        g = gname[i]
        if i <= SKIN_LAST:
            r = ("chest_and_shoulders" if chest_mask[i] else "face" if head_mask[i] and g == "face"
                 else "scalp_and_ears" if head_mask[i] else "neck")
        else:
            r = ("mouth_interior" if g == "mouth_socket" else "eye_socket" if "socket" in g
                 else "teeth" if g == "teeth" else "gums_and_tongue" if g == "gums_and_tongue"
                 else "eyelashes" if "lashes" in g else "eye" if g.startswith(("eyeball", "lacrimal"))
                 else "eye_helper")
        region[i] = REGIONS.index(r)

    vertex_uv = np.zeros((n, 2))
    flat_v, flat_t = mesh.faces.ravel(), mesh.uv_faces.ravel()
    first = np.unique(flat_v[::-1], return_index=True)  # last occurrence in reversed = first
    vertex_uv[first[0]] = mesh.uvs[flat_t[::-1][first[1]]]
    au_names, au = facs_au_table(names)
    arrays = {
        "template_vertices": v.astype(np.float32),
        "faces": mesh.faces.astype(np.int32), "uvs": mesh.uvs.astype(np.float32),
        "uv_faces": mesh.uv_faces.astype(np.int32),
        "face_material": mesh.face_material.astype(np.int16),
        "material_names": np.array(mesh.materials), "vertex_uv": vertex_uv.astype(np.float32),
        "vertex_group": group, "group_names": np.array([g[0] for g in GROUPS]),
        "vertex_region": region, "region_names": np.array(REGIONS),
        "landmark_indices": landmarks,
        "shape_components": comps.astype(np.float32), "shape_std": std.astype(np.float32),
        "expression_basis": (ict["expressions"] * CM).astype(np.float32),
        "expression_names": np.array(names), "au_names": au_names, "au_matrix": au,
        "joint_names": np.array(JOINT_NAMES), "joint_parents": np.array(PARENTS, dtype=np.int32),
        "joint_regressor": regressor.astype(np.float32),
        "skinning_weights": weights.astype(np.float32),
        "rotation_limits_deg": rotation_limits_deg().numpy().astype(np.float32),
    }
    meta = {
        "name": "hack-default-ict",
        "units": "metres; Y up; face looks along +Z; right-handed",
        "source": "ICT-FaceKit light model (USC Institute for Creative Technologies, 2020), MIT "
                  "licence; see LICENSE-ICT-FaceKit",
        "provenance": {
            "template": "captured (ICT-FaceKit generic neutral mesh, cm -> m)",
            "shape_space": f"captured (orthonormal PCA of ICT-FaceKit's {len(ict['identity'])} "
                           "identity modes; beta ~ N(0, I))",
            "expressions": "captured (ICT-FaceKit's 53 generic ARKit-named shapes), FACS AU "
                           "table checked against FACS 2002 (ict_default.AU_TABLE)",
            "skeleton": "derived (8 joints placed from anatomical priors on the template: "
                        "surface landmarks, vertebral sizes, 20 deg lordosis, "
                        f"{int(DEPTH_FRACTION * 100)} % depth at c7-t1, the column moved back "
                        "to lie 12 mm behind the pharynx's posterior wall; regressor = "
                        "non-negative affine "
                        "vertex weights). Not learned from ultrasound/CT.",
            "skinning_weights": "derived (procedural from the spine and a head cut, Laplacian "
                                "smoothed); not learned",
            "rotation_limits": "literature (White & Panjabi 1990)",
            "personalised_expressions": "not yet learned (absent)",
            "pose_blendshapes": "not yet learned (absent)",
            "larynx": "not yet learned (absent)",
        },
        "landmarks": {"notch_y_m": float(placed["notch_y"]), "ear_lobe_m": placed["ear_lobe"].tolist()},
    }
    return arrays, meta
