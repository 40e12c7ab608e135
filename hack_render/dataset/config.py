"""Dataset configuration: defaults, a YAML file's overrides, validation naming the key.

A config is a nested mapping (see :data:`DEFAULTS` and docs/datasets.md). A YAML file
overrides any subset of it; unknown keys, wrong types, impossible ranges and unknown
presets are refused by :func:`load_config` / :func:`check_config` before anything is
rendered, with a message that names the key (``camera.yaw_deg``) and the fix.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

from hack_render.boundary import parse_yaml
from hack_render.dataset.backgrounds import check_background_config
from hack_render.errors import HackError
from hack_render.hair.style import ARCHETYPES, HairStyle
from hack_render.io.image import TONE_MAPS
from hack_render.render.scene import INTEGRATORS, MAX_SIDE, MAX_SPP, SAMPLERS
from hack_render.render.settings import RenderSettings
from scenes import lights

#: Every key, with its default. Ranges are [min, max] (uniform unless said otherwise).
DEFAULTS: dict[str, Any] = {
    "render": {
        "resolution": 256,        # pixels, square
        "spp": 25,                # samples per pixel (auto: 25 is the orthogonal array's)
        "max_depth": 8,
        "tonemap": "aces",        # rgb.png tone map: aces, reinhard, clip
        "soft_mask_samples": 3,   # soft masks: k x k sub-pixel rays per pixel (0: hard only)
        "variant": None,          # Mitsuba variant (None: automatic)
        "sampler": "auto",        # Mitsuba sampler (render/settings.py SAMPLERS)
        "integrator": "hack_path",  # hack_path, volpath or path (render/settings.py INTEGRATORS)
        "denoise": "off",         # OIDN (extra 'denoise'): off, auto (noisy if missing), on
        "keep_noisy": False,      # with denoise: also write rgb_noisy.exr
        "sss": False,             # subsurface scattering in the skin (2x render time)
    },
    "identity": {
        "components": 20,         # beta ~ N(0, I) in the first k shape components
        "truncation": 2.5,        # |beta_k| <= truncation (resampled beyond)
    },
    "expression": {
        "aus": "all",             # action units to draw from ("all" or a list of names)
        "max_active": 3,          # 0..max_active AUs active at once (uniform count)
        "p_neutral": 0.1,         # probability of a neutral face
        "intensity": [0.2, 1.0],  # weight of each active AU
    },
    "neck": {
        # whole-head (flexion X, axial Y, lateral Z) ~ N(0, std), truncated at 2 std,
        # shared over the 8 joints by their ranges (distribute_head_rotation)
        "head_std_deg": [15.0, 30.0, 10.0],
        "joint_noise_deg": 1.5,   # independent per-joint, per-axis noise (std)
    },
    "larynx": {
        "eta": [0.6, 1.4],        # larynx size
        "tau_rest": [-0.003, 0.003],  # vertical slide at rest, metres
        "p_swallow": 0.3,         # probability that the sample is mid-swallow
        "swallow_height": 0.015,  # peak slide of a swallow, metres (phase ~ U(0, 1))
    },
    "appearance": {
        "source": "seed",         # seed (procedural subjects), alpha (PCA model), constant
        "subjects": 100000,       # seed: subject ids drawn from [0, subjects)
        # seed: "projected" (the subject generated at 64 px and projected onto A(alpha),
        # maps at `height`: ~0.1 s a sample, the same skin tones) or "generated" (the full
        # generator at `height`: ~1 s a sample, every freckle); docs/datasets.md
        "maps": "projected",
        "components": 20,         # alpha: first k components, alpha ~ N(0, I)
        "truncation": 2.5,        # alpha: |alpha_k| <= truncation
        "height": 256,            # skin map height H (maps are H x 2H)
    },
    "lighting": {
        "presets": ["studio", "light_stage", "overcast_sun", "window"],  # or env:PATH.exr
        "rotation_deg": [-180.0, 180.0],
        "exposure": [-0.5, 0.5],  # stops
    },
    "background": {
        "source": "photos",       # photos (scikit-image's shipped photos) or environment
        "photos": "all",          # or a list of names (dataset/backgrounds.py PHOTOS)
        "crop": [0.35, 1.0],      # crop side, fraction of the photo's short side
        "luminance": [0.03, 0.3],  # mean linear luminance (log-uniform)
    },
    "hair": {
        # sampled (the population sampler, hair.style.sample_style: archetype, colour,
        # brows, lashes, beard), none (no strands at all: the bald mannequin with lash
        # cards), an archetype name (everyone gets it, the rest sampled), or a mapping of
        # the params file's hair fields (one style for everyone, each person's own strands)
        "style": "sampled",
        # level of detail of every groom (1: >= 50k scalp strands, 1-15 s to grow);
        # docs/datasets.md has the cost per sample
        "lod": 0.5,
        # grooms pooled: each person keeps their own archetype, beard and colour, and
        # their strands are one of about this many grooms (dataset.sampling.pool_entries:
        # per archetype and beard as often as the sampler draws them, at least one); a
        # pooled groom is grown once and recoloured after. 0: everyone's own groom
        "pool": 32,
    },
    "camera": {
        "views": 1,               # cameras per sample (a multi-view group of one scene)
        "yaw_deg": [-60.0, 60.0],
        "pitch_deg": [-10.0, 20.0],
        "distance_scale": [0.9, 1.25],  # x the distance that frames the head and neck
        "focal_mm": [50.0, 105.0],      # on a 36 mm sensor
    },
}


#: Sections that may be given as one value, standing for one key of theirs
#: (``hair: none`` is ``hair: {style: none}``).
SHORTHANDS = {"hair": "style"}
#: ``hair.style`` names besides the archetypes.
HAIR_SOURCES = ("sampled", "none")

#: How ``appearance.source: seed`` makes a subject's maps (``appearance.projected`` or
#: ``appearance.generator``).
SEED_MAPS = ("projected", "generated")


def _fail(key: str, expected: str, found) -> None:
    raise HackError(f"config key '{key}': expected {expected}, found {found!r}.")


def _merge(base: dict, override: dict, prefix: str = "") -> dict:
    out = copy.deepcopy(base)
    for k, v in override.items():
        key = f"{prefix}{k}"
        if k not in base:
            raise HackError(f"config key '{key}': unknown key; known keys here: "
                            f"{', '.join(base)}. Check its spelling (docs/datasets.md).")
        if isinstance(base[k], dict):
            if k in SHORTHANDS and not prefix and (v is None or isinstance(v, str)):
                v = {SHORTHANDS[k]: "none" if v is None else v}
            if not isinstance(v, dict):
                _fail(key, "a mapping", v)
            out[k] = _merge(base[k], v, f"{key}.")
        else:
            out[k] = v
    return out


def _number(cfg, section, name, lo=-math.inf, hi=math.inf, integer=False):
    key = f"{section}.{name}"
    v = cfg[section][name]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
        _fail(key, "an integer" if integer else "a number", v)
    if not (lo <= v <= hi) or not math.isfinite(v):
        _fail(key, f"a value in [{lo}, {hi}]", v)


def _range(cfg, section, name, lo=-math.inf, hi=math.inf):
    key = f"{section}.{name}"
    v = cfg[section][name]
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
        _fail(key, "[min, max], two numbers", v)
    a, b = float(v[0]), float(v[1])
    if not (math.isfinite(a) and math.isfinite(b)):
        _fail(key, "finite numbers", v)
    if a > b:
        _fail(key, "[min, max] with min <= max (an impossible range otherwise)", v)
    if a < lo or b > hi:
        _fail(key, f"a range inside [{lo}, {hi}]", v)
    cfg[section][name] = [a, b]


def check_config(cfg: dict) -> dict:
    """Validate a full config (defaults merged); returns it with ranges as float lists."""
    _number(cfg, "render", "resolution", 8, MAX_SIDE, integer=True)
    _number(cfg, "render", "spp", 1, MAX_SPP, integer=True)
    _number(cfg, "render", "max_depth", 1, 64, integer=True)
    _number(cfg, "render", "soft_mask_samples", 0, 16, integer=True)
    if cfg["render"]["tonemap"] not in TONE_MAPS:
        _fail("render.tonemap", f"one of {', '.join(TONE_MAPS)}", cfg["render"]["tonemap"])
    var = cfg["render"]["variant"]
    if var is not None and not isinstance(var, str):
        _fail("render.variant", "a Mitsuba variant name or null", var)
    _number(cfg, "identity", "components", 0, 10000, integer=True)
    _number(cfg, "identity", "truncation", 0.1, 10.0)
    aus = cfg["expression"]["aus"]
    if aus != "all" and (not isinstance(aus, list) or not all(isinstance(a, str) for a in aus)):
        _fail("expression.aus", "'all' or a list of action-unit names", aus)
    _number(cfg, "expression", "max_active", 0, 64, integer=True)
    _number(cfg, "expression", "p_neutral", 0.0, 1.0)
    _range(cfg, "expression", "intensity", -2.0, 2.0)
    hs = cfg["neck"]["head_std_deg"]
    if (not isinstance(hs, (list, tuple)) or len(hs) != 3
            or not all(isinstance(x, (int, float)) and 0 <= x <= 180 for x in hs)):
        _fail("neck.head_std_deg", "3 standard deviations in [0, 180] degrees "
              "(flexion, axial, lateral)", hs)
    cfg["neck"]["head_std_deg"] = [float(x) for x in hs]
    _number(cfg, "neck", "joint_noise_deg", 0.0, 45.0)
    _range(cfg, "larynx", "eta", 0.0, 10.0)
    _range(cfg, "larynx", "tau_rest", -0.05, 0.05)
    _number(cfg, "larynx", "p_swallow", 0.0, 1.0)
    _number(cfg, "larynx", "swallow_height", 0.0, 0.05)
    src = cfg["appearance"]["source"]
    if src not in ("seed", "alpha", "constant"):
        _fail("appearance.source", "seed, alpha or constant", src)
    _number(cfg, "appearance", "subjects", 1, 2 ** 31 - 1, integer=True)
    if cfg["appearance"]["maps"] not in SEED_MAPS:
        _fail("appearance.maps", f"one of {', '.join(SEED_MAPS)}", cfg["appearance"]["maps"])
    _number(cfg, "appearance", "components", 0, 10000, integer=True)
    _number(cfg, "appearance", "truncation", 0.1, 10.0)
    _number(cfg, "appearance", "height", 16, 4096, integer=True)
    presets = cfg["lighting"]["presets"]
    if isinstance(presets, str):
        presets = cfg["lighting"]["presets"] = [presets]
    if not isinstance(presets, list) or not presets:
        _fail("lighting.presets", "a non-empty list of lighting presets", presets)
    for name in presets:
        if not isinstance(name, str):
            _fail("lighting.presets", "preset names (studio, light_stage, overcast_sun, "
                  "window) or env:PATH.exr", name)
        try:
            lights.preset(name, 0.0, 0.0)
        except HackError as err:
            raise HackError(f"config key 'lighting.presets': {err}") from err
    _range(cfg, "lighting", "rotation_deg", -3600.0, 3600.0)
    _range(cfg, "lighting", "exposure", -20.0, 20.0)

    check_background_config(cfg, _fail)

    if cfg["render"]["sampler"] not in SAMPLERS:
        _fail("render.sampler", f"one of {', '.join(SAMPLERS)}", cfg["render"]["sampler"])
    if cfg["render"]["integrator"] not in INTEGRATORS:
        _fail("render.integrator", f"one of {', '.join(INTEGRATORS)}",
              cfg["render"]["integrator"])
    if cfg["render"]["denoise"] not in ("off", "auto", "on"):
        _fail("render.denoise", "off, auto or on", cfg["render"]["denoise"])
    for key in ("keep_noisy", "sss"):
        if not isinstance(cfg["render"][key], bool):
            _fail(f"render.{key}", "true or false", cfg["render"][key])
    _check_hair(cfg)
    _number(cfg, "camera", "views", 1, 1024, integer=True)
    _range(cfg, "camera", "yaw_deg", -360.0, 360.0)
    _range(cfg, "camera", "pitch_deg", -89.0, 89.0)
    _range(cfg, "camera", "distance_scale", 0.05, 100.0)
    _range(cfg, "camera", "focal_mm", 1.0, 2000.0)
    return cfg


def _check_hair(cfg: dict) -> None:
    style = cfg["hair"]["style"]
    names = (*HAIR_SOURCES, *ARCHETYPES)
    if isinstance(style, str):
        if style not in names:
            _fail("hair.style", f"one of {', '.join(names)} or a mapping of hair fields "
                  "(the params file's hair section, hack_render/hair/style.py)", style)
    elif isinstance(style, dict):
        try:
            HairStyle.from_dict(style)
        except HackError as err:
            raise HackError(f"config key 'hair.style': {err}") from err
    else:
        _fail("hair.style", f"one of {', '.join(names)} or a mapping of hair fields", style)
    _number(cfg, "hair", "lod", 0.01, 4.0)
    _number(cfg, "hair", "pool", 0, 100_000, integer=True)


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> dict:
    """Defaults, then a YAML/JSON file's values, then ``overrides``; validated.

    Raises:
        HackError: unreadable file, unknown key, bad value (the message names the key).
    """
    cfg = copy.deepcopy(DEFAULTS)
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise HackError(f"--config {path}: file not found.")

        try:
            data = parse_yaml(path.read_text()) or {}
        except HackError as err:  # a duplicate key
            raise HackError(f"--config {path}: {err}") from err
        except Exception as err:  # any parser error
            raise HackError(f"--config {path}: not valid YAML "
                            f"({str(err).splitlines()[0] if str(err) else err}).") from err
        if not isinstance(data, dict):
            raise HackError(f"--config {path}: expected a mapping of sections, found "
                            f"{type(data).__name__}.")
        cfg = _merge(cfg, data)
    if overrides:
        cfg = _merge(cfg, overrides)
    return check_config(cfg)


def canonical(cfg: dict) -> str:
    """The config as canonical JSON (sorted keys): equal strings mean equal datasets."""
    return json.dumps(cfg, sort_keys=True)


def render_settings(cfg: dict[str, Any]) -> RenderSettings:
    """The render settings of a config's ``render`` section, as every sample is rendered
    (a box pixel filter: each sample in one pixel, for the labels' and the denoiser's
    sake; seed 0, each view's seed set when it renders)."""
    r = cfg["render"]
    return RenderSettings(r["resolution"], r["resolution"], r["spp"], r["max_depth"], 0,
                          pixel_filter="box", sampler=r["sampler"], integrator=r["integrator"])
