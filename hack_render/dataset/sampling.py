"""Sampling one dataset item: a pure function of (config, seed, index).

Every component draws from its own generator ``numpy.random.default_rng([seed, index,
stream])``, so sample i never depends on which samples were drawn before it (sharding,
order and resumption cannot change it), and changing one section of the config (say the
camera ranges) leaves every other component of every sample unchanged.

The result is plain JSON-ready data (lists and floats); :func:`model_kwargs` turns it into
the geometry model's forward arguments.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from hack_render.dataset.backgrounds import sample_background
from hack_render.geometry.rotations import axis_angle_to_euler, euler_to_axis_angle
from hack_render.geometry.skeleton import clamp_to_limits, distribute_head_rotation, outside_limits
from hack_render.hair.style import (
    ARCHETYPE_DEFAULTS,
    ARCHETYPES,
    BEARD_FREQUENCIES,
    BEARDS,
    COLOUR_FIELDS,
    STYLE_FREQUENCIES,
    HairStyle,
    sample_style,
)
from hack_render.render.turntable import swallow_tau

#: Generator stream per component (never reorder: it would change every dataset).
STREAMS = {"identity": 1, "expression": 2, "neck": 3, "larynx": 4, "appearance": 5,
           "lighting": 6, "camera": 7, "render": 8, "background": 9, "hair": 10,
           "hair_pool": 11}


def _rng(seed: int, index: int, stream: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(index), STREAMS[stream]])


def truncated_normal(rng: np.random.Generator, n: int, limit: float, std=1.0) -> np.ndarray:
    """n draws of N(0, std^2) conditioned on |x| <= limit * std (by redrawing)."""
    std = np.broadcast_to(np.asarray(std, dtype=np.float64), (n,))
    x = rng.standard_normal(n)
    bad = np.abs(x) > limit
    while bad.any():
        x[bad] = rng.standard_normal(int(bad.sum()))
        bad = np.abs(x) > limit
    return x * std


def sample_identity(cfg: dict, rng) -> list[float]:
    c = cfg["identity"]
    return truncated_normal(rng, c["components"], c["truncation"]).tolist()


def sample_expression(cfg: dict, rng, au_names: tuple[str, ...]) -> dict[str, float]:
    """A sparse combination of action units: {name: weight}, empty for a neutral face."""
    c = cfg["expression"]
    pool = list(au_names) if c["aus"] == "all" else list(c["aus"])
    if rng.random() < c["p_neutral"] or c["max_active"] == 0 or not pool:
        return {}
    k = int(rng.integers(1, min(c["max_active"], len(pool)) + 1))
    chosen = sorted(rng.choice(len(pool), size=k, replace=False).tolist())
    lo, hi = c["intensity"]
    return {pool[j]: float(rng.uniform(lo, hi)) for j in chosen}


def sample_neck(cfg: dict, rng) -> tuple[list[float], list[list[float]]]:
    """Whole-head angles (degrees) and the final per-joint theta (8, 3) axis-angle.

    The head rotation (truncated at 2 std) is shared over the joints in proportion to
    their ranges (``distribute_head_rotation``), each joint's Euler angles get independent
    noise, and the result is clamped to the anatomical limits (``clamp_to_limits``).
    """
    c = cfg["neck"]
    head = truncated_normal(rng, 3, 2.0, c["head_std_deg"])
    noise = rng.standard_normal((8, 3)) * c["joint_noise_deg"]
    base = distribute_head_rotation(torch.deg2rad(torch.tensor(head, dtype=torch.float64)))
    e = axis_angle_to_euler(base) + torch.deg2rad(torch.tensor(noise, dtype=torch.float64))
    theta = clamp_to_limits(euler_to_axis_angle(e))
    return head.tolist(), theta.tolist()


def sample_larynx(cfg: dict, rng) -> dict:
    """eta (size), tau (slide, metres) and the swallow phase in [0, 1) or None."""
    c = cfg["larynx"]
    eta = float(rng.uniform(*c["eta"]))
    tau = float(rng.uniform(*c["tau_rest"]))
    phase = float(rng.random()) if rng.random() < c["p_swallow"] else None
    if phase is not None:
        tau += swallow_tau(phase, c["swallow_height"])
    return {"eta": eta, "tau": tau, "swallow_phase": phase}


def sample_appearance(cfg: dict, rng) -> dict:
    c = cfg["appearance"]
    if c["source"] == "seed":
        return {"source": "seed", "subject": int(rng.integers(0, c["subjects"]))}
    if c["source"] == "alpha":
        return {"source": "alpha",
                "alpha": truncated_normal(rng, c["components"], c["truncation"]).tolist()}
    return {"source": "constant"}


def sample_lighting(cfg: dict, rng) -> dict:
    c = cfg["lighting"]
    return {"preset": c["presets"][int(rng.integers(0, len(c["presets"])))],
            "rotation_deg": float(rng.uniform(*c["rotation_deg"])),
            "exposure": float(rng.uniform(*c["exposure"]))}


def sample_cameras(cfg: dict, rng) -> list[dict]:
    """One camera description per view (yaw, pitch, distance scale, focal length)."""
    c = cfg["camera"]
    return [{"yaw_deg": float(rng.uniform(*c["yaw_deg"])),
             "pitch_deg": float(rng.uniform(*c["pitch_deg"])),
             "distance_scale": float(rng.uniform(*c["distance_scale"])),
             "focal_mm": float(rng.uniform(*c["focal_mm"]))} for _ in range(c["views"])]


def pool_entries(pool: int, archetype: str, beard: str) -> int:
    """How many grooms ``hair.pool`` gives the people of one archetype and beard: ``pool``
    times the pair's frequency in the population sampler, rounded, at least 1."""
    return max(1, round(pool * STYLE_FREQUENCIES[archetype] * BEARD_FREQUENCIES[beard]))


def pool_size(pool: int) -> int:
    """How many grooms ``hair.pool`` gives in all (:func:`pool_entries` over every
    archetype and beard); 0: no pool."""
    return 0 if pool <= 0 else sum(pool_entries(pool, a, b) for a in ARCHETYPES for b in BEARDS)


def pool_style(seed: int, drawn: HairStyle, pool: int, rng) -> HairStyle:
    """The person's hair with a pooled groom (``hair.pool``): their own archetype, beard
    and colour (:data:`~hack_render.hair.style.COLOUR_FIELDS`), the rest (the groom's seed,
    length, curl, hairline, brows, lashes, ...) from one of :func:`pool_entries` draws of
    the sampler for that archetype and beard, picked by ``rng``; each draw its own stream,
    so a pooled style, like the person's, is a function of (seed, index) alone."""
    n = pool_entries(pool, drawn.archetype, drawn.beard)
    j = int(rng.integers(n))
    kind = ARCHETYPES.index(drawn.archetype) * len(BEARDS) + BEARDS.index(drawn.beard)
    entry = sample_style(np.random.default_rng([int(seed), j, STREAMS["hair_pool"], kind]),
                         drawn.lod, archetype=drawn.archetype, beard=drawn.beard)
    return replace(entry, **{k: getattr(drawn, k) for k in COLOUR_FIELDS})


def sample_hair(cfg: dict, rng, seed: int = 0) -> dict | None:
    """The person's hair (the params file's ``hair`` section, ``HairStyle.to_dict()``) or
    None (``hair.style: none``). ``hair.pool`` > 0: the groom's shape is pooled
    (:func:`pool_style`, ``seed`` the dataset's) before the rules below.

    ``sampled``: :func:`hack_render.hair.style.sample_style` at ``hair.lod``. An archetype
    name: the same draw (colour, brows, lashes, beard, hairline, parting, the groom's
    seed) with that archetype and its defaults for length, curl, volume and gravity. A
    mapping: that style for everyone, with the draw's groom seed (each person's own
    strands) unless it gives ``seed``, and ``hair.lod`` unless it gives ``lod``. The draw
    is made in every case, so ``hair.style`` changes no other draw."""
    c = cfg["hair"]
    style = c["style"]
    if style == "none":
        return None
    drawn = sample_style(rng, float(c["lod"]))
    if c["pool"]:
        drawn = pool_style(seed, drawn, int(c["pool"]), rng)
    if style == "sampled":
        return drawn.to_dict()
    if isinstance(style, str):
        fixed = set(ARCHETYPE_DEFAULTS[style]) | {"archetype"}
        keep = {k: v for k, v in drawn.to_dict().items() if k not in fixed}
        return HairStyle.archetype_style(style, **keep).to_dict()
    given = HairStyle.from_dict(style)
    return replace(given, seed=given.seed if "seed" in style else drawn.seed,
                   lod=given.lod if "lod" in style else float(c["lod"])).to_dict()


def sample_spec(cfg: dict, seed: int, index: int, au_names: tuple[str, ...]) -> dict:
    """Everything that defines sample ``index`` of the dataset with ``seed``.

    Returns a JSON-ready dict: beta, expression (AU weights), head_rotation_deg, theta,
    eta, tau, swallow_phase, appearance, lighting, cameras, render_seed, background, hair
    (a ``HairStyle.to_dict()`` or None).
    """
    head, theta = sample_neck(cfg, _rng(seed, index, "neck"))
    spec = {"index": int(index), "seed": int(seed),
            "beta": sample_identity(cfg, _rng(seed, index, "identity")),
            "expression": sample_expression(cfg, _rng(seed, index, "expression"), au_names),
            "head_rotation_deg": head, "theta": theta}
    spec.update(sample_larynx(cfg, _rng(seed, index, "larynx")))
    spec["appearance"] = sample_appearance(cfg, _rng(seed, index, "appearance"))
    spec["lighting"] = sample_lighting(cfg, _rng(seed, index, "lighting"))
    spec["cameras"] = sample_cameras(cfg, _rng(seed, index, "camera"))
    spec["render_seed"] = int(_rng(seed, index, "render").integers(0, 2 ** 31 - 1024))

    spec["background"] = sample_background(cfg, _rng(seed, index, "background"))
    spec["hair"] = sample_hair(cfg, _rng(seed, index, "hair"), seed)
    return spec


def model_kwargs(model, spec: dict) -> dict[str, torch.Tensor]:
    """Forward arguments (batch 1) of the geometry model for a sample."""
    dtype = model.template.dtype
    psi = model.expression_vector(spec["expression"]) if spec["expression"] else \
        torch.zeros(model.num_expressions, dtype=dtype)
    kw = {"psi": psi[None], "theta": torch.tensor([spec["theta"]], dtype=dtype),
          "eta": torch.tensor([spec["eta"]], dtype=dtype),
          "tau": torch.tensor([spec["tau"]], dtype=dtype)}
    if spec["beta"]:
        kw["beta"] = torch.tensor([spec["beta"]], dtype=dtype)
    return kw


def params_file(model, spec: dict) -> dict:
    """The sample as a ``hack-render render --params`` file (``geometry.params`` format):
    re-rendering it with the same lighting and camera reproduces the geometry, and its
    ``hair`` section (``HairStyle.to_dict()``, null for no hair) the strands."""
    psi = model_kwargs(model, spec)["psi"][0]
    out = {"beta": list(spec["beta"]), "psi": [float(x) for x in psi.tolist()],
           "theta": spec["theta"], "eta": spec["eta"], "tau": spec["tau"]}
    if not out["beta"]:
        del out["beta"]
    out["hair"] = spec.get("hair")
    return out


def degrees_within_limits(theta) -> bool:
    """True when every joint angle of theta (8, 3) is inside the anatomical limits."""
    return not outside_limits(torch.as_tensor(theta, dtype=torch.float64), tol_deg=1e-6)


__all__ = ["STREAMS", "degrees_within_limits", "model_kwargs", "params_file", "pool_entries",
           "pool_size", "pool_style", "sample_hair",
           "sample_spec", "truncated_normal"]
