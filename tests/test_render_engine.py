"""Variant choice: preference order, fallbacks, overrides, and the LLVM message."""

import warnings

import pytest

from hack_render.errors import HackError
from hack_render.render.engine import ENV_VAR, Backends, VariantWarning, choose_variant

ALL = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")


def backends(cuda=True, llvm=True, version=(19, 1, 7), variants=ALL):
    return Backends(variants, cuda, llvm, version if llvm else (0, 0, 0))


@pytest.fixture(autouse=True)
def no_env(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)


def test_01_prefers_cuda_then_llvm():
    assert choose_variant(backends=backends()) == "cuda_ad_rgb"
    assert choose_variant(backends=backends(cuda=False)) == "llvm_ad_rgb"


def test_02_falls_back_to_scalar_with_install_hint():
    with pytest.warns(VariantWarning, match="apt-get install libllvm19"):
        assert choose_variant(backends=backends(cuda=False, llvm=False)) == "scalar_rgb"


def test_03_too_old_llvm_is_not_used():
    with pytest.warns(VariantWarning, match=r"LLVM 15\.0\.7 is too old"):
        assert choose_variant(backends=backends(cuda=False, version=(15, 0, 7))) == "scalar_rgb"


def test_04_env_var_and_flag_override(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "scalar_rgb")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an explicit choice does not warn
        assert choose_variant(backends=backends()) == "scalar_rgb"
        assert choose_variant("llvm_ad_rgb", backends=backends()) == "llvm_ad_rgb"


def test_05_unusable_explicit_variant_is_an_error():
    with pytest.raises(HackError, match="libllvm19"):
        choose_variant("llvm_ad_rgb", backends=backends(cuda=False, llvm=False))
    with pytest.raises(HackError, match="no working CUDA"):
        choose_variant("cuda_ad_rgb", backends=backends(cuda=False))
    with pytest.raises(HackError, match="no variant 'llvm_ad_spectral'"):
        choose_variant("llvm_ad_spectral", backends=backends())


def test_06_this_machine_gets_a_jit_variant():
    from hack_render.render.engine import probe_backends

    b = probe_backends()
    if not (b.llvm or b.cuda):
        pytest.skip("no JIT backend on this machine")
    assert choose_variant(backends=b) in ("cuda_ad_rgb", "llvm_ad_rgb")


def test_atomic_outputs_are_ordinary_readable_files(tmp_path, monkeypatch):
    """Files written through a temporary name get the permissions the umask gives any new
    file (mkstemp alone would leave them 0600, unreadable to a user's group), and an
    interrupted write leaves neither the file nor the temporary."""
    import hack_render.io as io

    assert io._UMASK == io._read_umask()  # read at import
    for umask, mode in ((0o022, 0o644), (0o027, 0o640)):
        monkeypatch.setattr(io, "_UMASK", umask)
        with io.atomic_path(tmp_path / f"{mode:o}.json") as tmp:
            tmp.write_text("{}")
        assert (tmp_path / f"{mode:o}.json").stat().st_mode & 0o777 == mode
    with pytest.raises(KeyboardInterrupt):
        with io.atomic_path(tmp_path / "b.json") as tmp:
            tmp.write_text("partial")
            raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["640.json", "644.json"]
