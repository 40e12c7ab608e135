"""The fit config's keys (issue 64): what a user sets is a config key whose comment says
what it trades; the fitter's internal constants are not. A config that still sets one of
the former keys (``config.REMOVED``) is refused naming it, unless it sets the value the
constant now has (a config copied from an older fit's ``fit_report.json``), which is
ignored with a warning."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import json
import re
import warnings

import pytest

from hack_render.errors import HackError
from hack_render.fit import config as fc


def _constant(path: str):
    """The value behind a REMOVED entry's name: ``module.NAME``, or a function's default
    (``module.function(arg=value)``)."""
    if "(" in path:
        mod, func = path.split("(")[0].rsplit(".", 1)
        arg = path.split("(")[1].split("=")[0]
        fn = getattr(importlib.import_module(mod), func)
        return inspect.signature(fn).parameters[arg].default
    mod, name = path.rsplit(".", 1)
    return getattr(importlib.import_module(mod), name)


def test_removed_keys_are_constants_of_the_same_value():
    """Every former key names a constant that exists and holds the value the key had, and
    none is still a field."""
    cfg = fc.FitConfig()
    for section, keys in fc.REMOVED.items():
        fields = {f.name for f in dataclasses.fields(getattr(cfg, section))}
        for key, (path, value) in keys.items():
            assert key not in fields, f"{section}.{key} is still a field"
            got = _constant(path)
            assert got == value and type(got) is type(value), (section, key, path, got)


def test_every_remaining_field_has_a_comment():
    """Each settable field (of the sections and the top level) has a comment in config.py,
    on its line or above it (a group of fields, e.g. resolutions and iterations, shares
    the comment above the group): what moving it trades."""
    field_line = re.compile(r"^\s+\w+: [^#]+=")
    cfg = fc.FitConfig()
    for obj in [getattr(cfg, f.name) for f in dataclasses.fields(cfg)] + [cfg]:
        if not dataclasses.is_dataclass(obj):
            continue
        lines = inspect.getsource(type(obj)).splitlines()
        for f in dataclasses.fields(obj):
            if dataclasses.is_dataclass(getattr(obj, f.name)):
                continue
            i = next(k for k, ln in enumerate(lines) if ln.strip().startswith(f"{f.name}:"))
            j = i
            while j > 0 and field_line.match(lines[j - 1]):
                j -= 1
            assert "#" in lines[i] or lines[j - 1].strip().startswith("#"), \
                f"{type(obj).__name__}.{f.name}: no comment says what it trades"


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_a_removed_key_with_another_value_is_refused_naming_it(tmp_path, suffix):
    path = tmp_path / f"old{suffix}"
    if suffix == ".toml":
        path.write_text("[camera]\niterations = 60\nlr = 0.1\n")
    else:
        path.write_text(json.dumps({"camera": {"iterations": 60, "lr": 0.1}}))
    with pytest.raises(HackError) as err:
        fc.load_config(path)
    msg = str(err.value)
    assert "camera.lr" in msg and "no longer a setting" in msg
    assert "hack_render.fit.geometric.CAMERA_LR" in msg and "0.03" in msg and "0.1" in msg
    # the same from the command line's and the benches' overrides
    with pytest.raises(HackError, match=r"overrides\.final\.denoise: no longer a setting"):
        fc.load_config(None, {"final": {"denoise": "off"}})
    # a misspelt key is still an unknown key, not a removed one
    with pytest.raises(HackError, match="unknown key 'lrr'"):
        fc.load_config(None, {"camera": {"lrr": 0.03}})


def test_a_removed_key_at_its_fixed_value_is_ignored_with_a_warning(tmp_path):
    """An older fit's whole config (its fit_report.json's "config": every key, the former
    ones at their defaults) still loads, warning once per former key, and gives today's
    defaults; values equal as numbers count (1 for 1.0)."""
    old = fc.FitConfig().to_dict()
    for section, keys in fc.REMOVED.items():
        for key, (_, value) in keys.items():
            old[section][key] = value
    old["shape"]["w_rot"] = 1  # an int where the constant is a float
    path = tmp_path / "report_config.json"
    path.write_text(json.dumps(old))
    with pytest.warns(fc.ConfigWarning) as rec:
        cfg = fc.load_config(path)
    assert cfg == fc.FitConfig()
    n = sum(len(keys) for keys in fc.REMOVED.values())
    assert len([w for w in rec if issubclass(w.category, fc.ConfigWarning)]) == n
    assert any("landmarks.huber_px: no longer a setting" in str(w.message) for w in rec)
    # a bool is not the number 1
    with pytest.raises(HackError, match="landmarks.detector_upsample"):
        fc.load_config(None, {"landmarks": {"detector_upsample": True}})


def test_todays_config_loads_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cfg = fc.load_config(None, fc.FitConfig().to_dict())
    assert cfg == fc.FitConfig()
    assert fc.load_config(None, fc.tiny_overrides()).photometric.resolutions == [24]
