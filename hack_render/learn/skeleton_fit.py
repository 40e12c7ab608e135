"""Placing the 8 cervical joints on a template and expressing them as a joint regressor.

No ultrasound or CT labels exist for the default model, so the joints are placed from the
anatomical priors of the shared ANATOMY.md (standard surface anatomy; White & Panjabi 1990
sizes) on the template's own surface, then written as an affine combination of skin
vertices (a regressor J, rows summing to 1, non-negative), so J(beta) follows identity.

Placement, in the sagittal plane (metres, Y up, face +Z):
  * suprasternal notch = T2 level: the most posterior point of the front midline profile
    between the chin-neck angle and the chest; c7-t1 sits 1.5 cm above it (ANATOMY.md:
    1-2 cm);
  * o-c1 sits 1 cm above the ear-lobe bottom (C1 transverse process at the ear lobe, the
    atlanto-occipital joint just above and medial), 0.5 cm in front of the lobe (the
    occipital condyles lie anterior to the mastoid tips);
  * c7-t1 lies at 55 % of the neck's front-to-back depth from the front skin (ANATOMY.md:
    55-65 %; the lower end, because the template's lower back-of-neck includes the
    trapezius slope);
  * between them, joints at cumulative anatomical heights (vertebral bodies C3-C7 14.5 mm,
    discs 5 mm, C2 to the c1-c2 joint 25 mm, C1 to o-c1 15 mm) along a curve from c7-t1
    to o-c1 that bows forward with a 20 degree Cobb angle (lordosis, apex at c4-c5);
  * the vertebral bodies lie behind the pharynx (ANATOMY.md): where the template has a
    mouth socket reaching down the throat, the column is moved back, by a shift growing
    linearly from 0 at c7-t1 to its largest at o-c1, until every joint at the socket's
    height lies PHARYNX_MARGIN_M behind the socket's posterior (midline) wall: the
    retropharyngeal soft tissue in front of C2-C4 is under 7 mm thick in adults, and a
    cervical body's centre lies about 8 mm behind its front (bodies about 15-16 mm deep;
    Gopalakrishnan et al. 1990, White & Panjabi 1990).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import lsq_linear

# Distances from c7-t1 upwards along the column, metres (ANATOMY.md sizes).
_BODY, _DISC = 0.0145, 0.005
_CUM = np.cumsum([0.0, _BODY + _DISC, _BODY + _DISC, _BODY + _DISC, _BODY + _DISC,
                  _BODY + _DISC, 0.025, 0.015])  # c7-t1 ... o-c1
DEPTH_FRACTION = 0.55
COBB_DEG = 20.0  # cervical lordosis C2-C7 in neutral standing, ANATOMY.md: 15-25 degrees
# joint centre behind the pharynx's posterior wall: prevertebral soft tissue (< 7 mm at
# C2-C4) plus half a vertebral body's depth (~8 mm); see the module docstring
PHARYNX_MARGIN_M = 0.012


def pharynx_wall(template: np.ndarray, socket_idx: np.ndarray, y: np.ndarray,
                 half_width: float = 0.01, half_height: float = 0.005) -> np.ndarray:
    """Posterior wall (min z) of the mouth socket's midline slice at heights y (K,);
    NaN where the socket does not reach that height."""
    sock = template[socket_idx]
    mid = sock[np.abs(sock[:, 0]) < half_width]
    out = np.full(len(y), np.nan)
    for k, yk in enumerate(y):
        sl = mid[np.abs(mid[:, 1] - yk) < half_height]
        if len(sl):
            out[k] = sl[:, 2].min()
    return out


def behind_pharynx(joints: np.ndarray, template: np.ndarray, socket_idx: np.ndarray,
                   margin: float = PHARYNX_MARGIN_M) -> np.ndarray:
    """Joints (K, 3) moved back (-z) by ``d * t_k`` (t_k: 0 at c7-t1 to 1 at o-c1, by
    column length), with the smallest d >= 0 that puts every joint at the socket's height
    ``margin`` behind its posterior wall."""
    t = _CUM / _CUM[-1]
    wall = pharynx_wall(template, socket_idx, joints[:, 1])
    need = joints[:, 2] - (wall - margin)
    ok = np.isfinite(need) & (t > 0)
    d = float(np.max(np.clip(need[ok] / t[ok], 0, None), initial=0.0))
    out = joints.copy()
    out[:, 2] -= d * t
    return out


def midline_profiles(skin: np.ndarray, half_width: float = 0.005):
    """Front (max z) and back (min z) of the midline slice |x| < half_width as functions of y.

    Returns (ys, front_z, back_z) sampled every 5 mm over the slice's height range.
    """
    mid = skin[np.abs(skin[:, 0]) < half_width]
    ys = np.arange(mid[:, 1].min() + 0.0025, mid[:, 1].max(), 0.005)
    front, back = [], []
    for y in ys:
        sl = mid[np.abs(mid[:, 1] - y) < 0.005]
        front.append(sl[:, 2].max() if len(sl) else np.nan)
        back.append(sl[:, 2].min() if len(sl) else np.nan)
    return ys, np.asarray(front), np.asarray(back)


def place_joints(template: np.ndarray, skin_idx: np.ndarray, chin_idx: int,
                 socket_idx: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Anatomical joint positions (8, 3) on a template, plus the landmarks used.

    Args:
        template: (N, 3) metres.
        skin_idx: indices of skin vertices (face and head-and-neck groups).
        chin_idx: the chin landmark vertex (Multi-PIE 8), which bounds the neck from above.
        socket_idx: the mouth socket's vertices (the mouth and pharynx surface): the
            column is placed behind it (:func:`behind_pharynx`); None skips that step.
    """
    skin = template[skin_idx]
    ys, front, back = midline_profiles(skin)
    y_chin = template[chin_idx, 1]
    # Neck front: below the chin; notch = most posterior front point above the chest.
    neck = (ys < y_chin - 0.01) & (ys > skin[:, 1].min() + 0.02) & np.isfinite(front)
    y_notch = ys[neck][np.argmin(front[neck])]
    y_c7 = y_notch + 0.015
    f = lambda arr, y: float(np.interp(y, ys[np.isfinite(arr)], arr[np.isfinite(arr)]))
    z_c7 = f(front, y_c7) - DEPTH_FRACTION * (f(front, y_c7) - f(back, y_c7))
    # Ear lobe: lowest vertex of the lateral ear region (|x| beyond the skull, near z = 0).
    lateral = skin[(np.abs(skin[:, 0]) > 0.07) & (np.abs(skin[:, 2]) < 0.03)
                   & (skin[:, 1] > y_chin) & (skin[:, 1] < 0.07)]
    lobe = lateral[np.argmin(lateral[:, 1])]
    oc1 = np.array([0.0, lobe[1] + 0.01, lobe[2] + 0.005])
    c7 = np.array([0.0, y_c7, z_c7])
    # Lordosis: the column bows forward (concave backwards) with its apex at c4-c5. A
    # circular arc whose end tangents differ by the Cobb angle has sagitta c/2 tan(angle/4).
    frac = _CUM / _CUM[-1]
    t_mid = frac[3]
    chord = oc1 - c7
    perp = np.array([0.0, -chord[2], chord[1]]) / np.linalg.norm(chord)  # anterior normal
    sagitta = 0.5 * np.linalg.norm(chord) * np.tan(np.deg2rad(COBB_DEG) / 4)
    mid = c7 + t_mid * chord + perp * sagitta * 4 * t_mid * (1 - t_mid)
    ctrl = (mid - (1 - t_mid) ** 2 * c7 - t_mid**2 * oc1) / (2 * t_mid * (1 - t_mid))
    t = np.linspace(0, 1, 2001)[:, None]
    curve = (1 - t) ** 2 * c7 + 2 * t * (1 - t) * ctrl + t**2 * oc1
    arc = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    joints = np.stack([curve[np.searchsorted(arc, fr * arc[-1]).clip(0, 2000)] for fr in frac])
    joints[0], joints[-1] = c7, oc1
    if socket_idx is not None and len(socket_idx):
        joints = behind_pharynx(joints, template, np.asarray(socket_idx))
    return {"joints": joints, "notch_y": np.array(y_notch), "ear_lobe": lobe, "curve": curve}


def affine_regressor(template: np.ndarray, anchor_idx: np.ndarray, joints: np.ndarray,
                     slab: float = 0.012, smooth: float = 0.05) -> np.ndarray:
    """Non-negative affine weights over skin vertices reproducing each joint on the template.

    For joint k, the anchors are the skin vertices within ``slab`` of its height (a ring
    around the neck or head); weights w >= 0 solve sum w = 1 and sum w v = j_k exactly (to
    least squares) while ``smooth`` * ||w|| spreads them around the ring, so the joint
    follows the whole cross-section under identity changes.

    Returns:
        (K, N) regressor.
    """
    reg = np.zeros((len(joints), len(template)))
    for k, j in enumerate(joints):
        ring = anchor_idx[np.abs(template[anchor_idx, 1] - j[1]) < slab]
        a = np.vstack([template[ring].T * 100.0, np.ones((1, len(ring))) * 10.0,
                       smooth * np.eye(len(ring))])
        b = np.concatenate([j * 100.0, [10.0], np.zeros(len(ring))])
        w = lsq_linear(a, b, bounds=(0, 1), method="bvls").x
        w /= w.sum()
        reg[k, ring] = w
    return reg
