"""The eyes' colour gains and gloss solved from the renders' affine shares
(:mod:`hack_render.fit.iris` builds the rows: per pixel the photo, what comes from neither
part, the iris's, the whites' and the gloss's shares): bounded linear least squares per
channel with the gloss tied to the whites (:func:`gains`), then over the photo's lid
openings the same in sRGB-encoded values (:func:`encoded_gains`), the gloss solved with
the colours where the whites tie it below :data:`FREE_GLOSS_BELOW`. Pure numpy/scipy."""

from __future__ import annotations

import numpy as np

_LUMA = np.array([0.2126, 0.7152, 0.0722])

#: The eye whites' colour is held within these bounds (linear RGB, per channel).
SCLERA_BOUNDS = (0.02, 0.9)
#: The same over the photo's lid openings (``opening``): the lower bound the iris's. A
#: photo's colour cast that the light does not take (the light-colour prior leaves it in
#: the skin's albedo: a sepia print, Grace Hopper's) is in the eyes' whites too; her
#: whites, (113, 44, 32) in sRGB under a grey light 2.5 times the default, need an albedo
#: of (0.066, 0.010, 0.006), below 0.02 in green and blue: held there, they came out
#: grey-blue beside her red-brown skin.
SCLERA_BOUNDS_OPENING = (0.005, 0.9)
#: Over the photo's lid openings (``opening``), a gloss that :func:`gains` ties to the
#: whites (their luminance gain, or its cap) below this is solved again with the colours,
#: one share of the three channels (:func:`encoded_gains`): whites this dark say that the
#: light over-lights the eyes several times over, and the proxy is fragile there.
#: obama_speech's kept fit: tied 0.16 (0.007 once the mouth's stage had moved his face by
#: 0.3 of one identity unit, his eyes' figure 22.2 and 23.4 dB), solved 0 (23.9 dB;
#: docs/fit.md). The solved gloss only comes down from the tied one (as the cap): solved
#: both ways it is poorly determined (the renders are not quite affine in it), and
#: raised it cost obama's kept fit 0.66 dB (0.08 -> 0.16). Above the threshold the tied
#: gloss stays: on the model's own renders the solve took a true 0.4 that the whites had
#: right (0.39) to 0.54, and a true 1 to 0.6-0.7 with the iris 30-50 % too bright.
FREE_GLOSS_BELOW = 0.3

def affine_fit(p: np.ndarray, s: np.ndarray, d: np.ndarray, bounds: list) -> np.ndarray:
    """Per channel, the gains x (k,) >= 0 within ``bounds`` (k pairs) that minimise
    sum (p - s - sum_k x_k d_k)^2: p, s (n,), d (n, k)."""
    from scipy.optimize import lsq_linear

    lo, hi = zip(*bounds)
    return lsq_linear(d, p - s, bounds=(np.asarray(lo), np.asarray(hi))).x


def iris_gloss(p: np.ndarray, rest: np.ndarray, di: np.ndarray, dg: np.ndarray) -> float:
    """The gloss (0..1) that, with the iris's three gains (>= 0), best explains the iris's
    pixels: one bounded least-squares solve over the three channels together (p, rest,
    di, dg (n, 3): the photo, the render without the iris's and the gloss's shares, and
    those shares)."""
    from scipy.optimize import lsq_linear

    n = len(p)
    a = np.zeros((3 * n, 4))
    for c in range(3):
        a[c * n:(c + 1) * n, c] = di[:, c]
        a[c * n:(c + 1) * n, 3] = dg[:, c]
    b = (p - rest).T.reshape(-1)
    return float(lsq_linear(a, b, bounds=(np.zeros(4), [np.inf] * 3 + [1.0])).x[3])


def gains(rows, s0: np.ndarray, iris_ok: bool, white_ok: bool, gloss_tied: bool,
           hold_iris: bool, iris_rows=None, bounds=SCLERA_BOUNDS
           ) -> tuple[np.ndarray, np.ndarray, float]:
    """(the iris's gains, the whites' gains, the gloss): per channel one bounded linear
    least-squares solve (``hold_iris``: the iris at its colour); the gloss (where
    ``gloss_tied``) the whites' luminance gain, at most 1 (the same light that makes the
    whites too bright makes the gloss so), solved in turn with them (eight rounds). Where
    the iris comes out black in a channel, the gloss alone is brighter than the photo's
    iris (a broad light's veil over a dark iris): the gloss is then capped at its least
    squares over the iris's pixels (``iris_rows``), the colours held; the cap only comes
    down."""
    p, s_, di, ds, dg = rows
    lo_w, hi_w = (b / s0 for b in bounds)
    gloss, cap, gi, gw = 1.0, 1.0, np.ones(3), np.ones(3)
    for _ in range(8 if white_ok and gloss_tied else 1):
        base = s_ - (1.0 - gloss) * dg          # the rest, with the gloss at its share
        gi, gw = np.ones(3), np.ones(3)
        for c in range(3):
            if white_ok and not hold_iris:
                gi[c], gw[c] = affine_fit(p[:, c], base[:, c], np.stack(
                    [di[:, c], ds[:, c]], 1), [(0.0, np.inf), (lo_w[c], hi_w[c])])
            elif white_ok:
                gw[c] = affine_fit(p[:, c], base[:, c] + di[:, c], ds[:, [c]],
                                    [(lo_w[c], hi_w[c])])[0]
            elif iris_ok:
                gi[c] = max(0.0, (p[:, c] - base[:, c] - ds[:, c]).sum() / di[:, c].sum())
        if white_ok and gloss_tied:
            k = np.ones(len(p), bool) if iris_rows is None else iris_rows
            if not hold_iris and np.any(gi <= 1e-6) and (dg[k] ** 2).sum() > 0:
                cap = min(cap, iris_gloss(p[k], s_[k] - dg[k] + ds[k] * gw, di[k], dg[k]))
            gloss = min(cap, float(np.clip((s0 * gw) @ _LUMA / (s0 @ _LUMA), 0.0, 1.0)))
    return gi, gw, gloss


def encoded_gains(rows, s0: np.ndarray, gi: np.ndarray, gw: np.ndarray, gloss: float,
                   bounds=SCLERA_BOUNDS_OPENING, free_gloss: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, float]:
    """The iris's and the whites' gains (and with ``free_gloss`` the gloss) refined so
    that the renders match the photo in sRGB-encoded values (what the eyes' figure
    compares, and the eye sees: the linear solve weighs a bright pixel's error most, the
    catchlights and the whites, so a dark iris comes out too light), from the linear
    solution, within the same bounds (the iris's at least 0, the whites' ``bounds``, the
    gloss from 0 to the given one). Without ``free_gloss`` each channel is solved alone,
    the gloss held; with it the three channels together, the gloss one share of all three
    (see :data:`FREE_GLOSS_BELOW` for where :func:`hack_render.fit.iris.estimate` frees it). Returns (gi, gw,
    gloss)."""
    import colour
    from scipy.optimize import least_squares

    p, s_, di, ds, dg = rows
    lo_w, hi_w = (b / s0 for b in bounds)

    def enc(x):
        return colour.cctf_encoding(np.clip(x, 0.0, 1.0))

    gi, gw = gi.copy(), gw.copy()
    x0 = np.clip(np.stack([gi, gw], 1), np.stack([np.zeros(3), lo_w], 1),
                 np.stack([np.full(3, np.inf), hi_w], 1))
    x0[:, 1] = np.minimum(np.maximum(x0[:, 1], lo_w + 1e-9), hi_w - 1e-9)
    if free_gloss:
        target = enc(p)

        def res_all(x):
            g = x[6]
            lin = s_ - (1.0 - g) * dg + x[0:6:2] * di + x[1:6:2] * ds
            return (enc(lin) - target).ravel()

        # the gloss only comes down from the tied one (as gains' cap): the whites say
        # the light over-lights the eyes at least that much
        start = np.append(x0.ravel(), gloss * (1.0 - 1e-6))
        lo = np.append(np.stack([np.zeros(3), lo_w], 1).ravel(), 0.0)
        hi = np.append(np.stack([np.full(3, np.inf), hi_w], 1).ravel(), gloss)
        sol = least_squares(res_all, start, bounds=(lo, hi))
        return sol.x[0:6:2].copy(), sol.x[1:6:2].copy(), float(sol.x[6])
    base = s_ - (1.0 - gloss) * dg
    for c in range(3):
        target = enc(p[:, c])

        def res(x, c=c, target=target):
            return enc(base[:, c] + x[0] * di[:, c] + x[1] * ds[:, c]) - target

        sol = least_squares(res, x0[c], bounds=([0.0, lo_w[c]], [np.inf, hi_w[c]]))
        gi[c], gw[c] = sol.x
    return gi, gw, gloss
