"""The hair layer's style space: :class:`HairStyle`, its archetypes, the params file's
``hair`` section, and the population sampler.

A style is a handful of documented numbers (no wig library): the scalp hair's archetype,
length, curl, volume, gravity, hairline and parting; the brows' density, thickness and arch;
the lashes' length and curl; the beard; the colour as melanin concentrations. The groom
(:mod:`hack_render.hair.groom`) turns a style into strands rooted on the model's skin.

Colour is melanin, as in Mitsuba's ``hair`` BSDF (d'Eon et al. 2011; Chiang et al. 2016):
``eumelanin`` about 0.3 for blonde, 1.3 for brown and 8 for black hair (pbrt-v3's hair
material notes, Pharr, Jakob & Humphreys 2016, section 9.3; the same figures in rayrender's
``hair`` documentation); ``pheomelanin`` makes hair red; ``greying`` is the fraction of
strands without pigment (white), ``variation`` the per-strand spread of the melanin
(Blender's Principled Hair BSDF calls it *Random Color*: each strand's melanin times
``1 + variation * u``, ``u`` uniform in [-1, 1]).

The population sampler (:func:`sample_style`) draws colour from :data:`COLOUR_FREQUENCIES`
(cited there) and styles from :data:`STYLE_FREQUENCIES`, which are *chosen for variety*, not
measured: no survey of hairstyles across populations was found to cite; they are labelled
so wherever they are written.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from hack_render.errors import HackError

#: Scalp archetypes, in the order of the docs.
ARCHETYPES = ("bald", "shaved", "crew", "short", "bob", "long", "ponytail", "bun", "afro")
BEARDS = ("none", "stubble", "goatee", "full")
PARTINGS = ("none", "left", "right", "centre")

#: What each archetype sets (length in metres; the rest 0..1); the other fields keep the
#: style's values. ``bald`` grows no scalp strands.
ARCHETYPE_DEFAULTS: dict[str, dict[str, Any]] = {
    "bald": {"length": 0.0},
    "shaved": {"length": 0.003, "curl": 0.0, "volume": 0.0, "gravity": 0.0},
    "crew": {"length": 0.014, "curl": 0.0, "volume": 0.15, "gravity": 0.1},
    "short": {"length": 0.06, "curl": 0.1, "volume": 0.35, "gravity": 0.5},
    "bob": {"length": 0.17, "curl": 0.05, "volume": 0.3, "gravity": 1.0},
    "long": {"length": 0.30, "curl": 0.15, "volume": 0.35, "gravity": 1.0},
    "ponytail": {"length": 0.26, "curl": 0.05, "volume": 0.1, "gravity": 1.0},
    "bun": {"length": 0.22, "curl": 0.0, "volume": 0.1, "gravity": 0.6},
    "afro": {"length": 0.09, "curl": 0.95, "volume": 1.0, "gravity": 0.05},
}

#: Named colours (eumelanin, pheomelanin): ``--hair-color`` takes these or two numbers.
NAMED_COLOURS: dict[str, tuple[float, float]] = {
    "black": (8.0, 0.0), "dark-brown": (3.0, 0.1), "brown": (1.3, 0.1),
    "light-brown": (0.7, 0.15), "blonde": (0.3, 0.1), "platinum": (0.1, 0.02),
    "red": (0.5, 1.6), "auburn": (1.0, 1.0), "white": (0.0, 0.0),
}

#: Natural hair colour frequencies of the sampler, world population, by colour group.
#: Red hair about 1-2 % and blond hair about 2 % of people worldwide are the figures usually
#: quoted (reviews of pigmentation genetics, e.g. Rees 2003, "Genetics of hair and skin
#: color", Annu. Rev. Genet. 37:67-90); black and dark brown hair are the rest, black the
#: most common. The split between black and dark brown and among the lighter browns is
#: CHOSEN, not measured.
COLOUR_FREQUENCIES: dict[str, float] = {
    "black": 0.50, "dark-brown": 0.30, "brown": 0.10, "light-brown": 0.05,
    "blonde": 0.03, "red": 0.015, "auburn": 0.005,
}

#: Style frequencies of the sampler: CHOSEN FOR VARIETY, NOT MEASURED (see the module).
STYLE_FREQUENCIES: dict[str, float] = {
    "bald": 0.06, "shaved": 0.08, "crew": 0.14, "short": 0.22, "bob": 0.12, "long": 0.18,
    "ponytail": 0.08, "bun": 0.05, "afro": 0.07,
}
#: Beard frequencies of the sampler (chosen, not measured; sampled for every identity, as
#: the model has no sex parameter).
BEARD_FREQUENCIES: dict[str, float] = {"none": 0.62, "stubble": 0.18, "goatee": 0.07,
                                       "full": 0.13}

#: (min, max) of each numeric field.
RANGES: dict[str, tuple[float, float]] = {
    "length": (0.0, 0.6), "curl": (0.0, 1.0), "volume": (0.0, 1.0), "gravity": (0.0, 1.0),
    "hairline": (0.0, 1.0), "widows_peak": (0.0, 1.0), "density": (0.0, 2.0),
    "brow_density": (0.0, 2.0), "brow_thickness": (0.0, 2.0), "brow_arch": (-1.0, 1.0),
    "lash_length": (0.0, 2.0), "lash_curl": (0.0, 1.0), "beard_length": (0.0, 0.1),
    "eumelanin": (0.0, 20.0), "pheomelanin": (0.0, 20.0), "greying": (0.0, 1.0),
    "variation": (0.0, 0.9), "lod": (0.0, 4.0), "strand_radius": (1e-5, 1e-3),
}


#: The :class:`HairStyle` fields that only colour a groom (its strands' melanin): grooms of
#: styles that differ in nothing else have the same strands (``hair.groom.recolour``).
COLOUR_FIELDS = ("eumelanin", "pheomelanin", "greying", "variation")


@dataclass(frozen=True)
class HairStyle:
    """One person's hair, brows, lashes and beard (the params file's ``hair`` section).

    Attributes (units: metres for lengths, otherwise 0..1 unless said):
        archetype: one of :data:`ARCHETYPES`; sets ``length``, ``curl``, ``volume`` and
            ``gravity`` (:data:`ARCHETYPE_DEFAULTS`) unless those are given too.
        length: scalp strand length, metres (0: no scalp hair).
        curl: 0 straight ... 1 coily (the helix's radius grows and its period shrinks).
        volume: how far the hair stands off the scalp (0 lies flat, 1 stands out).
        gravity: how much long strands fall (0 keeps the growth direction).
        hairline: recession, 0 a full hairline ... 1 receded to the crown.
        widows_peak: a V at the front hairline's middle, 0 none ... 1 marked.
        parting: ``none`` (combed back), ``left``, ``right`` or ``centre``.
        density: scalp strands relative to the default count.
        brow_density, brow_thickness: relative (1 = average); brow_arch: -1 flat ... 1 high.
        lash_length: relative (1 = about 9 mm upper, 6 mm lower); lash_curl: 0 straight.
        beard: one of :data:`BEARDS`; beard_length: metres (stubble ignores it: 1 mm).
        eumelanin, pheomelanin: pigment concentrations of Mitsuba's ``hair`` BSDF.
        greying: fraction of unpigmented (white) strands; variation: per-strand spread.
        lod: level of detail, scales every strand count (1 = >= 50k scalp strands for a
            full head of hair; 0.1 for previews).
        strand_radius: scalp strand radius, metres (real hair: 0.03-0.05 mm; rendered
            strands are thicker and fewer, as in production grooms).
        seed: the groom's random seed (roots, spread, per-strand colour).
    """

    archetype: str = "short"
    length: float = 0.06
    curl: float = 0.1
    volume: float = 0.35
    gravity: float = 0.5
    hairline: float = 0.0
    widows_peak: float = 0.0
    parting: str = "left"
    density: float = 1.0
    brow_density: float = 1.0
    brow_thickness: float = 1.0
    brow_arch: float = 0.0
    lash_length: float = 1.0
    lash_curl: float = 0.5
    beard: str = "none"
    beard_length: float = 0.01
    eumelanin: float = 3.0
    pheomelanin: float = 0.1
    greying: float = 0.0
    variation: float = 0.15
    lod: float = 1.0
    strand_radius: float = 6e-5
    seed: int = 0

    def __post_init__(self):
        for name, (lo, hi) in RANGES.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or not lo <= value <= hi:
                raise HackError(f"hair.{name}: expected a number in [{lo:g}, {hi:g}], "
                                f"found {value!r}.")
        for name, allowed in (("archetype", ARCHETYPES), ("beard", BEARDS),
                              ("parting", PARTINGS)):
            if getattr(self, name) not in allowed:
                raise HackError(f"hair.{name}: expected one of {', '.join(allowed)}, found "
                                f"{getattr(self, name)!r}.")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise HackError(f"hair.seed: expected a non-negative integer, found {self.seed!r}.")

    @property
    def bald(self) -> bool:
        return self.archetype == "bald" or self.length <= 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def archetype_style(name: str, **overrides) -> HairStyle:
        """The archetype's defaults (:data:`ARCHETYPE_DEFAULTS`) with ``overrides``."""
        if name not in ARCHETYPES:
            raise HackError(f"hair archetype: expected one of {', '.join(ARCHETYPES)}, found "
                            f"{name!r}.")
        return HairStyle(**{"archetype": name, **ARCHETYPE_DEFAULTS[name], **overrides})

    @staticmethod
    def from_dict(data: Any) -> HairStyle:
        """A style from the params file's ``hair`` mapping: ``archetype`` first (its
        defaults), then the other keys; ``color`` may stand for the melanin pair (a name of
        :data:`NAMED_COLOURS` or ``[eumelanin, pheomelanin]``). Unknown keys are errors."""
        if data is None:
            return HairStyle.archetype_style("bald")
        if isinstance(data, str):
            return HairStyle.archetype_style(data)
        if not isinstance(data, dict):
            raise HackError(f"hair: expected a mapping or a style name, found "
                            f"{type(data).__name__}.")
        data = dict(data)
        known = {f.name for f in fields(HairStyle)} | {"color"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise HackError(f"hair: unknown key(s) {', '.join(unknown)}; expected some of "
                            f"{', '.join(sorted(known))}.")
        if "color" in data:
            eu, pheo = parse_colour(data.pop("color"))
            data.setdefault("eumelanin", eu)
            data.setdefault("pheomelanin", pheo)
        archetype = data.pop("archetype", "short")
        if not isinstance(archetype, str):
            raise HackError(f"hair.archetype: expected a name, found {archetype!r}.")
        return HairStyle.archetype_style(archetype, **data)

    def uncoloured(self) -> HairStyle:
        """This style without its colour (:data:`COLOUR_FIELDS` at their defaults): the key
        of its strands (``hair.groom.recolour``)."""
        return replace(self, **{k: HairStyle.__dataclass_fields__[k].default
                                for k in COLOUR_FIELDS})

    def with_colour(self, colour) -> HairStyle:
        eu, pheo = parse_colour(colour)
        return replace(self, eumelanin=eu, pheomelanin=pheo)


def pigment(style: HairStyle, tone: np.ndarray, white_draw: np.ndarray, darker: float = 1.0,
            grey: float = 1.0) -> np.ndarray:
    """(S, 2) melanin of strands with draws ``tone`` (S, 1), ``white_draw`` (S,) in
    ``style``'s colour (eumelanin darkened by ``darker``; greying scaled by ``grey``)."""
    base = np.array([style.eumelanin * darker, style.pheomelanin])
    m = base[None] * (1.0 + style.variation * tone)
    white = white_draw < style.greying * grey
    m[white] *= 0.02
    return np.clip(m, 0.0, 20.0)


def parse_colour(value) -> tuple[float, float]:
    """(eumelanin, pheomelanin) from a name of :data:`NAMED_COLOURS`, ``"EU,PHEO"`` or a
    pair of numbers."""
    if isinstance(value, str):
        key = value.strip().lower().replace("_", "-").replace(" ", "-")
        if key in NAMED_COLOURS:
            return NAMED_COLOURS[key]
        parts = key.split(",")
        try:
            value = [float(p) for p in parts]
        except ValueError:
            raise HackError(f"hair colour: expected one of {', '.join(NAMED_COLOURS)} or "
                            f"'EUMELANIN,PHEOMELANIN', found {value!r}.") from None
    if isinstance(value, (list, tuple)) and len(value) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            and 0 <= x <= 20 for x in value):
        return float(value[0]), float(value[1])
    raise HackError(f"hair colour: expected a name or two melanin values in [0, 20], found "
                    f"{value!r}.")


def _choice(rng: np.random.Generator, table: dict[str, float]) -> str:
    names = list(table)
    p = np.asarray([table[n] for n in names], np.float64)
    return names[int(rng.choice(len(names), p=p / p.sum()))]


def sample_style(rng: np.random.Generator, lod: float = 1.0, archetype: str | None = None,
                 beard: str | None = None) -> HairStyle:
    """One person's hair from the population sampler: colour by
    :data:`COLOUR_FREQUENCIES` (cited), style and beard by :data:`STYLE_FREQUENCIES` and
    :data:`BEARD_FREQUENCIES` (chosen, not measured), continuous fields uniform in ranges
    around each archetype's defaults, melanin jittered by up to 25 %. ``archetype``,
    ``beard``: given instead of drawn (the draws are made all the same)."""
    drawn = _choice(rng, STYLE_FREQUENCIES)
    archetype = drawn if archetype is None else archetype
    base = {"curl": 0.0, "volume": 0.0, "gravity": 0.0, **ARCHETYPE_DEFAULTS[archetype]}
    eu, pheo = NAMED_COLOURS[_choice(rng, COLOUR_FREQUENCIES)]
    jitter = float(rng.uniform(0.75, 1.25))
    greying = float(rng.uniform(0.0, 0.8)) if rng.random() < 0.2 else 0.0
    style = {
        "length": base["length"] * float(rng.uniform(0.8, 1.2)),
        "curl": float(np.clip(base["curl"] + rng.normal(0, 0.1), 0, 1))
        if archetype != "afro" else float(rng.uniform(0.8, 1.0)),
        "volume": float(np.clip(base["volume"] + rng.normal(0, 0.1), 0, 1)),
        "gravity": base["gravity"],
        "hairline": float(rng.uniform(0.0, 0.7)) if rng.random() < 0.25 else 0.0,
        "widows_peak": float(rng.uniform(0.0, 1.0)) if rng.random() < 0.2 else 0.0,
        "parting": str(rng.choice(PARTINGS)),
        "density": float(rng.uniform(0.8, 1.1)),
        "brow_density": float(rng.uniform(0.6, 1.4)),
        "brow_thickness": float(rng.uniform(0.7, 1.3)),
        "brow_arch": float(rng.uniform(-0.5, 0.8)),
        "lash_length": float(rng.uniform(0.8, 1.2)),
        "lash_curl": float(rng.uniform(0.3, 0.8)),
        "beard": _choice(rng, BEARD_FREQUENCIES),
        "beard_length": float(rng.uniform(0.004, 0.02)),
        "eumelanin": min(20.0, eu * jitter), "pheomelanin": min(20.0, pheo * jitter),
        "greying": greying, "variation": float(rng.uniform(0.1, 0.25)), "lod": lod,
        "seed": int(rng.integers(0, 2**31 - 1)),
    }
    if beard is not None:
        style["beard"] = beard
    return HairStyle(archetype=archetype, **style)


#: Absorption per unit concentration (per fibre radius) of eumelanin and pheomelanin, linear
#: RGB: the values of pbrt-v3's hair material (Pharr, Jakob & Humphreys 2016, section 9.3,
#: after d'Eon et al. 2011), which Mitsuba's ``hair`` BSDF ports.
EUMELANIN_SIGMA_A = np.array([0.419, 0.697, 1.37])
PHEOMELANIN_SIGMA_A = np.array([0.187, 0.4, 1.05])


def _chiang_factor(azimuthal_roughness: float = 0.3) -> float:
    b = azimuthal_roughness
    return 5.969 - 0.215 * b + 2.532 * b ** 2 - 10.73 * b ** 3 + 5.574 * b ** 4 + 0.245 * b ** 5


def melanin_colour(eumelanin, pheomelanin, azimuthal_roughness: float = 0.3) -> np.ndarray:
    """The hair's overall linear RGB colour (..., 3) for its melanin: Chiang et al. 2016
    ("A Practical and Controllable Hair and Fur Model for Production Path Tracing", section
    4.2) map a colour to the absorption that renders as it, ``sigma_a = (ln(c) / f(b))^2``;
    this is its inverse, ``c = exp(-sqrt(sigma_a) f(b))``, with sigma_a from the pigments
    (:data:`EUMELANIN_SIGMA_A`, :data:`PHEOMELANIN_SIGMA_A`) and Mitsuba's default azimuthal
    roughness 0.3."""
    eu = np.asarray(eumelanin, np.float64)[..., None]
    pheo = np.asarray(pheomelanin, np.float64)[..., None]
    sigma = eu * EUMELANIN_SIGMA_A + pheo * PHEOMELANIN_SIGMA_A
    return np.exp(-np.sqrt(sigma) * _chiang_factor(azimuthal_roughness))


def colour_melanin(rgb, azimuthal_roughness: float = 0.3) -> tuple[float, float]:
    """(eumelanin, pheomelanin) whose :func:`melanin_colour` is nearest to the linear RGB
    ``rgb`` (3,): non-negative least squares on the absorption the colour implies, both
    pigments clipped to [0, 20]."""
    c = np.clip(np.asarray(rgb, np.float64).reshape(3), 1e-4, 0.999)
    sigma = (np.log(c) / _chiang_factor(azimuthal_roughness)) ** 2
    a = np.stack([EUMELANIN_SIGMA_A, PHEOMELANIN_SIGMA_A], 1)
    best, best_err = (0.0, 0.0), np.inf
    # two unknowns, non-negative: the unconstrained solution, else each pigment alone
    cands = [np.linalg.lstsq(a, sigma, rcond=None)[0],
             np.array([max(float(sigma @ a[:, 0] / (a[:, 0] @ a[:, 0])), 0.0), 0.0]),
             np.array([0.0, max(float(sigma @ a[:, 1] / (a[:, 1] @ a[:, 1])), 0.0)])]
    for x in cands:
        if np.all(x >= 0):
            err = float(np.sum((a @ x - sigma) ** 2))
            if err < best_err:
                best, best_err = (float(min(x[0], 20.0)), float(min(x[1], 20.0))), err
    return best


def _albedo_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(eumelanin grid, pheomelanin grid, albedo (E, P, 3)) of hack_render/data/
    hair_albedo.json (measured by bench/hair_albedo.py)."""
    global _TABLE
    if _TABLE is None:
        data = json.loads((Path(__file__).resolve().parents[1] / "data" /
                           "hair_albedo.json").read_text())
        _TABLE = (np.asarray(data["eumelanin"], np.float64),
                  np.asarray(data["pheomelanin"], np.float64),
                  np.asarray(data["albedo"], np.float64))
    return _TABLE


_TABLE = None


def slab_albedo(eumelanin: float, pheomelanin: float) -> np.ndarray:
    """Linear RGB albedo (3,) of a thick layer of hair of this melanin as this project's
    renderer draws it (bilinear in the measured table, in the square roots of the
    concentrations, where the albedo changes evenly)."""
    eu_grid, ph_grid, table = _albedo_table()
    se, sp = np.sqrt(eu_grid), np.sqrt(ph_grid)
    x = np.sqrt(np.clip(eumelanin, eu_grid[0], eu_grid[-1]))
    y = np.sqrt(np.clip(pheomelanin, ph_grid[0], ph_grid[-1]))
    i = int(np.clip(np.searchsorted(se, x) - 1, 0, len(se) - 2))
    j = int(np.clip(np.searchsorted(sp, y) - 1, 0, len(sp) - 2))
    tx = (x - se[i]) / (se[i + 1] - se[i])
    ty = (y - sp[j]) / (sp[j + 1] - sp[j])
    return ((1 - tx) * (1 - ty) * table[i, j] + tx * (1 - ty) * table[i + 1, j]
            + (1 - tx) * ty * table[i, j + 1] + tx * ty * table[i + 1, j + 1])


def albedo_melanin(albedo) -> tuple[float, float]:
    """(eumelanin, pheomelanin) whose :func:`slab_albedo` is nearest to ``albedo`` (3,)
    linear RGB, in log colour (a dense search over the table's range)."""
    target = np.log(np.clip(np.asarray(albedo, np.float64).reshape(3), 1e-4, 1.0))
    eu_grid, ph_grid, _ = _albedo_table()
    eus = np.linspace(0, np.sqrt(eu_grid[-1]), 90) ** 2
    phs = np.linspace(0, np.sqrt(ph_grid[-1]), 40) ** 2
    best, best_err = (0.0, 0.0), np.inf
    for e in eus:
        for p in phs:
            err = float(np.sum((np.log(np.maximum(slab_albedo(e, p), 1e-4)) - target) ** 2))
            if err < best_err:
                best, best_err = (float(e), float(p)), err
    return best
