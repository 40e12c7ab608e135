"""The HACK model file (``geometry/model_file.py``): a validated round trip, clear errors
on bad files, and the cache of unpacked arrays."""

from __future__ import annotations

import numpy as np
import pytest

from hack_render.errors import HackError
from hack_render.geometry.model_file import load_model_file, save_model_file
from tests.synthetic import synthetic_arrays


def test_model_file_round_trip_and_errors(tmp_path):
    arrays = synthetic_arrays(seed=5)
    path = tmp_path / "m.npz"
    errors = save_model_file(path, arrays, {"provenance": {"all": "synthetic"}})
    loaded, meta = load_model_file(path)
    assert meta["provenance"]["all"] == "synthetic"
    for key, val in arrays.items():
        tol = 2 * errors.get(key, 0.0)
        if val.dtype.kind == "f":
            assert np.abs(loaded[key] - val).max() <= tol + 1e-12, key
        else:
            assert np.array_equal(loaded[key], val), key
    # truncated file
    data = path.read_bytes()
    bad = tmp_path / "trunc.npz"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(HackError, match="truncated or corrupt"):
        load_model_file(bad)
    # missing key, wrong shape, NaN, incomplete optional group
    for mutate, pattern in (
        (lambda a: a.pop("joint_regressor"), "missing required key 'joint_regressor'"),
        (lambda a: a.__setitem__("shape_std", a["shape_std"][:2]), "shape_std"),
        (lambda a: a["expression_basis"].__setitem__((0, 0, 0), np.nan), "non-finite"),
        (lambda a: a.pop("larynx_maps"), "optional group 'larynx' is incomplete"),
        (lambda a: a.__setitem__("bogus", np.zeros(3)), "unknown keys"),
    ):
        a = synthetic_arrays(seed=5)
        mutate(a)
        with pytest.raises(HackError, match=pattern):
            save_model_file(tmp_path / "x.npz", a, {})
    with pytest.raises(HackError, match="not found"):
        load_model_file(tmp_path / "nope.npz")


def test_model_file_cache_maps_the_same_arrays(tmp_path, monkeypatch):
    """The first load of a model file keeps its validated arrays unpacked in
    $XDG_CACHE_HOME/hack-render/models; the next load maps them (no pickle) and returns
    the same keys, dtypes and values as the file, writable without touching the cache; a
    rewritten file (new size or time) gets a new entry; a damaged entry is unpacked and
    written anew; only the newest CACHE_KEEP entries stay; an unwritable cache warns and
    loads anyway; HACK_RENDER_NO_CACHE=1 writes nothing."""
    from hack_render.geometry import model_file

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.delenv("HACK_RENDER_NO_CACHE", raising=False)
    root = tmp_path / "cache" / "hack-render" / "models"
    path = tmp_path / "m.npz"
    save_model_file(path, synthetic_arrays(seed=5), {"provenance": {"all": "synthetic"}})
    first, meta1 = load_model_file(path)
    (entry,) = root.iterdir()
    assert sorted(p.name for p in entry.iterdir()) == sorted(
        [f"{k}.npy" for k in first] + ["index.json"])
    second, meta2 = load_model_file(path)
    assert meta2 == meta1 and sorted(second) == sorted(first)
    for k, v in first.items():
        assert isinstance(second[k], np.memmap) and second[k].dtype == v.dtype, k
        assert np.array_equal(second[k], v), k
    # copy-on-write: a caller's change stays in its arrays
    second["template_vertices"][0, 0] += 1.0
    assert np.array_equal(load_model_file(path)[0]["template_vertices"],
                          first["template_vertices"])
    # a damaged entry: unpacked again, rewritten
    (entry / "faces.npy").write_bytes(b"\x93NUMPY broken")
    again, _ = load_model_file(path)
    assert np.array_equal(again["faces"], first["faces"])
    assert isinstance(load_model_file(path)[0]["faces"], np.memmap)
    # a changed file is a new entry; the oldest go beyond CACHE_KEEP
    for i in range(model_file.CACHE_KEEP + 1):
        other = tmp_path / f"m{i}.npz"
        save_model_file(other, synthetic_arrays(seed=6 + i), {})
        load_model_file(other)
    assert len(list(root.iterdir())) == model_file.CACHE_KEEP
    # a cache that cannot be written: a warning naming the fix, the arrays all the same
    monkeypatch.setenv("XDG_CACHE_HOME", str(path))  # a file, not a folder
    with pytest.warns(model_file.CacheWarning, match="HACK_RENDER_NO_CACHE"):
        arrays, _ = load_model_file(tmp_path / "m0.npz")
    assert sorted(arrays) == sorted(first)
    monkeypatch.setenv("HACK_RENDER_NO_CACHE", "1")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "off"))
    load_model_file(path)
    assert not (tmp_path / "off").exists()
