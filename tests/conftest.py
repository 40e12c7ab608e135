"""Shared test options: slow and GPU checks are opt-in, never deleted."""

import os
import shutil
import tempfile

import numpy as np
import pytest


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow")
    parser.addoption("--rungpu", action="store_true", help="also run tests marked gpu")


def pytest_configure(config):
    # the package's disk caches (posed meshes, sRGB thresholds) go to a folder of this
    # session, so that tests neither read nor fill the user's ~/.cache
    # (about 200 MB: the model's and the appearance model's caches; removed at the end)
    config._hack_cache = os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(
        prefix="hack-render-test-cache-")


def pytest_unconfigure(config):
    folder = getattr(config, "_hack_cache", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "slow" in item.keywords and not config.getoption("--runslow"):
            item.add_marker(pytest.mark.skip(reason="slow: run with --runslow"))
        if "gpu" in item.keywords and not config.getoption("--rungpu"):
            item.add_marker(pytest.mark.skip(reason="gpu: run with --rungpu"))


@pytest.fixture(scope="module")
def head_model():
    """(Topology, rest vertices (V, 3) float64) of the default model: the render tests'
    head (module scope: a test that edits the vertices affects its own module only)."""
    import torch

    from hack_render.geometry import load_default_model
    from hack_render.render.parts import Topology

    model = load_default_model()
    with torch.no_grad():
        v = model().vertices[0].double().numpy()
    return Topology.from_model(model), v


@pytest.fixture(scope="module")
def hair_head_model():
    """(Topology, rest vertices (V, 3) float64, HeadSurface) of the default model at the
    posing model's rest: the hair render tests' head and the surface grooms grow on."""
    from hack_render.geometry.model_file import default_model_path
    from hack_render.geometry.posing import PosingModel
    from hack_render.hair.regions import HeadSurface
    from hack_render.render.parts import Topology

    posing = PosingModel.from_file(default_model_path())
    return (Topology.from_model(posing), posing.vertices().astype(np.float64),
            HeadSurface.from_model(posing))


@pytest.fixture
def cli_in_process(capsys):
    """A function (*args) -> (returncode, stdout, stderr) that runs the console entry
    point (``hack_render.cli.main``) in this process, as ``python -m hack_render.cli``
    would: for tests of what a command does, not of a process's start (tests/test_cli.py's
    ``--help`` tests start real ones). Its warnings are shown on stderr as a fresh
    process prints them; the torch thread count a command sets is undone."""
    import sys
    import warnings
    from types import SimpleNamespace

    from hack_render.cli import main

    def cli(*args):
        capsys.readouterr()
        torch = sys.modules.get("torch")
        threads = torch.get_num_threads() if torch is not None else None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("default")   # a fresh process's filter
            try:
                main([str(a) for a in args])
                code = 0
            except SystemExit as exc:
                code = exc.code or 0
            finally:
                if threads is not None:
                    torch.set_num_threads(threads)
        cap = capsys.readouterr()
        shown = "".join(warnings.formatwarning(w.message, w.category, w.filename, w.lineno)
                        for w in caught)
        return SimpleNamespace(returncode=code, stdout=cap.out, stderr=cap.err + shown)

    return cli
