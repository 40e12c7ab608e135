"""The cornea's refraction of the iris for one camera, built into the iris's geometry.

Mitsuba 3's shadow rays do not pass a dielectric, so a true glass cornea in front of the
iris leaves the iris lit only by BSDF-sampled paths (about 30 % darker and grainy) and
black in the fitter's depth-2 renders. Instead the refraction is done geometrically, for
the camera alone: every iris (and pupil) vertex P is moved to P', where the camera sees
it through the cornea, and the iris is then lit and shaded where it appears (with its
true normals). Light paths from the lamps to the iris are not refracted: the iris is lit
as if it stood where it appears, up to 1 mm from where it is (an approximation; the
cornea's focusing of light onto the iris is left out). The iris's clearcoat stays the
cornea's wet specular, now at the apparent surface.

The optics (one refracting surface, as in the simplified schematic eyes):

- the cornea is a sphere of radius ``CORNEA_RADIUS`` = 7.8 mm (the anterior corneal
  radius of the schematic eyes; Millodot, *Dictionary of Optometry and Vision Science*,
  "constants of the eye", Table C7: anterior cornea 7.8 mm, posterior 6.7 mm);
- cornea and aqueous humour are one medium of index ``CORNEA_IOR`` = 1.336, the aqueous
  humour's (same table: cornea 1.376, aqueous 1.336). The 0.5 mm cornea is a near-
  concentric meniscus that deviates rays little by itself; the iris is seen through
  about 3 mm of aqueous, so the aqueous index is the better single value;
- the sphere passes through the limbus circle: radius ``parts.LIMBUS_RADIUS`` (5.8 mm)
  about the eye's optical axis (``parts.radial_eye_distance``), at the axial position
  where the model's outer eye shell (``M_Sclera*``) has that radius (the median over
  the shell's vertices within 0.5 mm of it: 14.8 mm in front of the eye's centre for
  ICT's eyes). Its apex is then R - sqrt(R^2 - r_L^2) = 2.6 mm in front of the limbus
  plane. The anterior chamber depth is what the mesh gives, not the ~3 mm of an eye
  (3.6 mm from the corneal apex to the lens, which the pupil's margin rests on): ICT's
  pupil lies 2.5 mm behind the apex, its iris 2.4 mm (median), because the iris disc
  sits a little in front of the limbus plane. The model's eye so refracts a little less
  than a real one: paraxial magnification 1.088 for the pupil, 1.11 at 3 mm.

For an iris point P and the camera centre C, the point Q on the sphere whose refracted
camera ray passes through P lies in the plane of C, P and the sphere's centre (the
plane of incidence holds the normal); there it is a 1-D root of the angle of Q, found by
a few vectorised Newton steps from the unrefracted hit. The apparent point P' lies on
the camera ray C->Q at |C - P'| = |C - Q| + |Q - P| / n: the reduced (apparent) depth of
P behind the cornea, exact for a flat interface, between the paraxial image of a
spherical surface (0.2 mm further) and P itself. It keeps P' behind the cornea (beyond
Q) and within about a millimetre of P (1.0 mm at most for ICT's iris), so the eyelids
and the eye's shell occlude it as they occlude the iris; the nearest point of the ray to
P would put it up to 0.6 mm deeper, further behind the shell's rim at oblique views. Points the cornea cannot show (in front of
the sphere, outside the limbus, on the far side of the eye, or with no refracted camera
ray) keep their place; at the limbus circle P' = P, so the iris stays continuous.

Eye frames follow the mesh: each eye's centre and axis at rest (``parts.split_parts``)
are carried to the posed mesh by the rigid fit (Kabsch) of that eye's vertices, so a
turned head or a gaze blendshape moves its cornea.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hack_render.errors import HackError
from hack_render.geometry.rigid import kabsch
from hack_render.render.parts import LIMBUS_RADIUS, radial_eye_distance

#: Anterior corneal radius, metres (schematic eye, see the module docstring).
CORNEA_RADIUS = 7.8e-3
#: Refractive index of cornea + aqueous humour as one medium (the aqueous humour's).
CORNEA_IOR = 1.336
#: Newton steps of the solver (quadratic convergence: 1e-15 rad after about 5).
NEWTON_STEPS = 8
#: Largest residual (sine of the angle between the refracted ray and Q->P) accepted.
RESIDUAL_TOL = 1e-9


@dataclass(frozen=True)
class CorneaSphere:
    """One eye's cornea in world space.

    Attributes: centre (3,) metres (the sphere's, not the eye's), axis (3,) unit, the
    optical axis pointing out of the eye; radius metres; limbus_radius metres; ior.
    The cap the cornea covers is the part of the sphere at distance >= sqrt(radius^2 -
    limbus_radius^2) in front of ``centre`` along ``axis``.
    """

    centre: np.ndarray
    axis: np.ndarray
    radius: float = CORNEA_RADIUS
    limbus_radius: float = LIMBUS_RADIUS
    ior: float = CORNEA_IOR

    def __post_init__(self):
        if not 0.0 < self.limbus_radius < self.radius:
            raise HackError(f"cornea: expected 0 < limbus radius < sphere radius, found "
                            f"{self.limbus_radius} and {self.radius} m.")
        if not 1.0 <= self.ior < 3.0:
            raise HackError(f"cornea: expected a refractive index in [1, 3), found {self.ior}.")

    @property
    def limbus_height(self) -> float:
        """Offset (metres) of the limbus plane in front of the sphere's centre."""
        return float(np.sqrt(self.radius ** 2 - self.limbus_radius ** 2))


def refract(d: np.ndarray, n: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """Snell's law. d (..., 3) unit incident directions, n (..., 3) unit normals facing
    against d, eta = n_outside / n_inside. Returns the unit refracted directions (..., 3)
    and a (...,) bool, False at total internal reflection (the direction is then 0)."""
    cos_i = -np.einsum("...i,...i->...", d, n)
    k = 1.0 - eta ** 2 * (1.0 - cos_i ** 2)
    ok = k >= 0.0
    t = eta * d + (eta * cos_i - np.sqrt(np.where(ok, k, 0.0)))[..., None] * n
    return np.where(ok[..., None], t, 0.0), ok


def trace(camera_centre: np.ndarray, points: np.ndarray,
          sphere: CorneaSphere) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The forward model (the reference the solver is tested against): camera rays from
    ``camera_centre`` (3,) through ``points`` (n, 3), refracted where they enter the
    sphere. Returns the entry points Q (n, 3), the refracted unit directions (n, 3) and
    a (n,) bool: the ray enters the sphere inside the limbus cap (else Q, t are NaN)."""
    c = np.asarray(camera_centre, np.float64)
    d = np.asarray(points, np.float64) - c
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    oc = c - sphere.centre
    b = d @ oc
    disc = b ** 2 - (oc @ oc - sphere.radius ** 2)
    s = -b - np.sqrt(np.where(disc > 0, disc, np.nan))
    q = c + s[:, None] * d
    normal = (q - sphere.centre) / sphere.radius
    t, ok = refract(d, normal, 1.0 / sphere.ior)
    ok &= (disc > 0) & (s > 0) & ((q - sphere.centre) @ sphere.axis >= sphere.limbus_height)
    return (np.where(ok[:, None], q, np.nan), np.where(ok[:, None], t, np.nan), ok)


def _residual(phi, c, p1, p2, radius, eta):
    """sin of the angle between the refracted ray at Q(phi) and Q->P, in the plane of
    incidence (camera at (c, 0), P at (p1, p2), sphere centre at the origin)."""
    nx, ny = np.cos(phi), np.sin(phi)
    qx, qy = radius * nx, radius * ny
    dx, dy = qx - c, qy
    norm = np.hypot(dx, dy)
    dx, dy = dx / norm, dy / norm
    cos_i = -(dx * nx + dy * ny)
    k = 1.0 - eta ** 2 * (1.0 - cos_i ** 2)
    m = eta * cos_i - np.sqrt(np.maximum(k, 0.0))
    tx, ty = eta * dx + m * nx, eta * dy + m * ny
    wx, wy = p1 - qx, p2 - qy
    return (tx * wy - ty * wx) / np.maximum(np.hypot(wx, wy), 1e-300)


def apparent_points(points: np.ndarray, camera_centre: np.ndarray,
                    sphere: CorneaSphere) -> tuple[np.ndarray, np.ndarray]:
    """Where the camera sees ``points`` (n, 3) metres, inside the cornea, through it.

    Returns (n, 3) apparent points P' (see the module docstring) and a (n,) bool: True
    where the point was moved; other points are returned unchanged.
    """
    p = np.asarray(points, np.float64).reshape(-1, 3)
    cam = np.asarray(camera_centre, np.float64).reshape(3)
    radius, eta = sphere.radius, 1.0 / sphere.ior
    e1 = cam - sphere.centre
    c = float(np.linalg.norm(e1))
    if c <= radius * (1.0 + 1e-9):  # the camera is in the eye: nothing to refract
        return p.copy(), np.zeros(len(p), bool)
    e1 /= c
    w = p - sphere.centre
    p1 = w @ e1
    perp = w - p1[:, None] * e1
    p2 = np.linalg.norm(perp, axis=1)
    # on the line camera-centre the plane of incidence is any plane through it
    spare = np.cross(e1, [1.0, 0.0, 0.0] if abs(e1[0]) < 0.9 else [0.0, 1.0, 0.0])
    e2 = np.where((p2 > 1e-12)[:, None], perp / np.maximum(p2, 1e-300)[:, None],
                  spare / np.linalg.norm(spare))
    # start from the unrefracted hit of the ray camera -> P (its angle from e1)
    dx, dy = p1 - c, p2
    dn = np.hypot(dx, dy)
    dx, dy = dx / np.maximum(dn, 1e-300), dy / np.maximum(dn, 1e-300)
    b = c * dx
    s = -b - np.sqrt(np.maximum(b ** 2 - (c ** 2 - radius ** 2), 0.0))
    phi = np.arctan2(s * dy, c + s * dx)
    h = 1e-7
    for _ in range(NEWTON_STEPS):
        g = _residual(phi, c, p1, p2, radius, eta)
        dg = (_residual(phi + h, c, p1, p2, radius, eta)
              - _residual(phi - h, c, p1, p2, radius, eta)) / (2 * h)
        step = np.where(np.abs(dg) > 1e-12, g / np.where(dg == 0, 1.0, dg), 0.0)
        phi = phi - np.clip(step, -0.2, 0.2)
    q = sphere.centre + radius * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    to_q = q - cam
    dist_q = np.linalg.norm(to_q, axis=1)
    qp = p - q
    dist_qp = np.linalg.norm(qp, axis=1)
    normal = (q - sphere.centre) / radius
    t, ok = refract(to_q / dist_q[:, None], normal, eta)
    ok &= np.abs(_residual(phi, c, p1, p2, radius, eta)) < RESIDUAL_TOL
    ok &= np.einsum("ij,ij->i", t, qp) > 0  # P ahead of Q along the refracted ray
    ok &= c * np.cos(phi) > radius  # Q faces the camera
    ok &= (q - sphere.centre) @ sphere.axis >= sphere.limbus_height  # inside the limbus
    ok &= np.linalg.norm(w, axis=1) < radius  # P behind the cornea
    out = cam + ((dist_q + dist_qp / sphere.ior) / dist_q)[:, None] * to_q
    return np.where(ok[:, None], out, p), ok


class CorneaRig:
    """The corneas of a head's eyes and the iris vertices they refract.

    Args:
        eye_vertices: per eye, the model-vertex indices (k,) of its shell and inner eye
            (their rigid motion carries the eye's frame).
        rest: (N, 3) rest vertices, metres. axes: the rest eye frames of
            ``parts.split_parts`` ([(centre (3,), axis (3,)), ...], same order).
        limbus_height: per eye, the axial offset (metres) of the limbus plane from the
            eye's centre (where the outer shell has radius ``LIMBUS_RADIUS``).
        iris_gather: (n,) model-vertex index of each iris-part vertex.
    """

    def __init__(self, eye_vertices, rest: np.ndarray, axes, limbus_height,
                 iris_gather: np.ndarray, radius: float = CORNEA_RADIUS,
                 ior: float = CORNEA_IOR):
        self.eye_vertices = [np.asarray(e, np.int64) for e in eye_vertices]
        self.rest_eyes = [rest[e] for e in self.eye_vertices]
        self.radius, self.ior = float(radius), float(ior)
        # the sphere's centre on the axis: the limbus circle lies on it
        back = float(np.sqrt(radius ** 2 - LIMBUS_RADIUS ** 2))
        self.rest_spheres = [(c + (h - back) * a, a) for (c, a), h in zip(axes, limbus_height)]
        self.iris_gather = np.asarray(iris_gather, np.int64)
        # which iris vertices each eye refracts: in front of its centre, inside the limbus
        p = rest[self.iris_gather]
        r, z = radial_eye_distance(p, axes)
        centres = np.stack([c for c, _ in axes])
        nearest = np.argmin(np.linalg.norm(p[:, None] - centres[None], axis=2), axis=1)
        inside = (r < LIMBUS_RADIUS) & (z > 0)
        self.iris_of_eye = [np.nonzero(inside & (nearest == i))[0] for i in range(len(axes))]

    @staticmethod
    def from_topology(topology, rest: np.ndarray, axes, iris_gather: np.ndarray,
                      radius: float = CORNEA_RADIUS, ior: float = CORNEA_IOR
                      ) -> CorneaRig | None:
        """The rig of an ICT-topology head (``M_Sclera*`` shells, ``M_Iris*`` inner
        eyes), or None when the model has no eyes to refract."""
        names = topology.material_names
        mats = [m for m in ("M_ScleraLeft", "M_ScleraRight", "M_IrisLeft", "M_IrisRight")
                if m in names]
        shells = [m for m in mats if m.startswith("M_Sclera")]
        if not axes or not shells or len(iris_gather) == 0:
            return None
        ids = np.unique(topology.faces[np.isin(topology.face_material,
                                               [names.index(m) for m in mats])])
        shell = np.unique(topology.faces[np.isin(topology.face_material,
                                                 [names.index(m) for m in shells])])
        centres = np.stack([c for c, _ in axes])
        side = np.argmin(np.linalg.norm(rest[ids][:, None] - centres[None], axis=2), axis=1)
        r, z = radial_eye_distance(rest[shell], axes)
        shell_side = np.argmin(np.linalg.norm(rest[shell][:, None] - centres[None], axis=2),
                               axis=1)
        heights = []
        for i in range(len(axes)):
            near = (shell_side == i) & (np.abs(r - LIMBUS_RADIUS) < 5e-4) & (z > 0)
            if near.sum() < 3:
                return None
            heights.append(float(np.median(z[near])))
        return CorneaRig([ids[side == i] for i in range(len(axes))], rest, axes, heights,
                         iris_gather, radius, ior)

    def spheres(self, vertices: np.ndarray) -> list[CorneaSphere]:
        """The corneas of the posed mesh ``vertices`` (N, 3), one per eye."""
        out = []
        for idx, rest, (centre, axis) in zip(self.eye_vertices, self.rest_eyes,
                                             self.rest_spheres):
            r, t = kabsch(rest, vertices[idx])
            out.append(CorneaSphere(r @ centre + t, r @ axis, self.radius, LIMBUS_RADIUS,
                                    self.ior))
        return out

    def iris_positions(self, vertices: np.ndarray, camera_centre: np.ndarray) -> np.ndarray:
        """(n, 3) positions of the iris part's vertices as ``camera_centre`` (3,) sees them
        through the corneas of the posed mesh ``vertices`` (N, 3), metres."""
        out = vertices[self.iris_gather].copy()
        for sphere, sel in zip(self.spheres(vertices), self.iris_of_eye):
            out[sel], _ = apparent_points(out[sel], camera_centre, sphere)
        return out
