"""The fitter's structure (issue 25, part 5): no import cycles among the fit modules
(function-local imports included), training and calibration code off the runtime path,
each module importable on its own in a fresh interpreter, and the names other packages
(the video tracker, the registration) import still there."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import hack_render

FIT = Path(hack_render.__file__).parent / "fit"


def _imports(path: Path) -> set[str]:
    """Every hack_render module a file imports, at any depth (top level or in a
    function), resolved to module names (``from pkg import mod`` counts as pkg.mod when
    that is a module)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("hack_render")}
        elif isinstance(node, ast.ImportFrom) and node.module and \
                node.module.startswith("hack_render"):
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                base = Path(hack_render.__file__).parent.joinpath(*sub.split(".")[1:])
                out.add(sub if base.with_suffix(".py").is_file() else node.module)
    return out


def _graph() -> dict[str, set[str]]:
    mods = {f"hack_render.fit.{p.stem}": p for p in FIT.glob("*.py") if p.stem != "__init__"}
    return {m: {d for d in _imports(p) if d in mods and d != m} for m, p in mods.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state, stack = {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                return stack[stack.index(d):] + [d]
            if d not in state:
                found = visit(d)
                if found:
                    return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m)
            if found:
                return found
    return None


def test_01_fit_import_graph_has_no_cycle():
    g = _graph()
    assert len(g) >= 15 and "hack_render.fit.state" in g and "hack_render.fit.terms" in g
    assert _cycle(g) is None, f"import cycle: {' -> '.join(_cycle(g))}"
    # the checker finds a planted cycle (it is not vacuous)
    planted = {k: set(v) for k, v in g.items()}
    planted["hack_render.fit.state"].add("hack_render.fit.photometric")
    assert _cycle(planted) is not None
    # stages and terms never reach back into the orchestrator
    for m in ("state", "terms", "geometric", "photometric", "stages", "robust", "camera"):
        assert "hack_render.fit.fitter" not in g[f"hack_render.fit.{m}"], m


def test_02_training_code_is_off_the_runtime_path():
    """Calibration and training live in hack_render.learn; only the CLI's learner
    commands (registered by `hack-render learn`) import them."""
    for p in FIT.glob("*.py"):
        learn = {d for d in _imports(p) if d.startswith("hack_render.learn")}
        assert not learn or p.stem == "cli", (p.name, learn)
    src = (FIT / "landmark_embedding.py").read_text() + (FIT / "landmark_refiner.py").read_text()
    for name in ("def calibrate(", "def render_subjects(", "def train(", "def build("):
        assert name not in src, name


@pytest.mark.slow
def test_03_each_module_imports_alone():
    names = sorted(p.stem for p in FIT.glob("*.py") if p.stem != "__init__")
    # each module first in a fresh interpreter (a cycle hidden by import order fails here)
    code = (f"import subprocess, sys\nmods = {names!r}\n"
            "bad = [m for m in mods if subprocess.run([sys.executable, '-c', "
            "'import hack_render.fit.' + m], capture_output=True).returncode]\nprint(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300, check=False)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_04_public_names_stay():
    from hack_render.fit.config import FitConfig  # noqa: F401
    from hack_render.fit.fitter import R0, FitResult, Fitter  # noqa: F401
    from hack_render.fit.landmark_embedding import LandmarkEmbedding, load_default  # noqa: F401
    from hack_render.fit.landmarks import Detection, JawContour, detect_landmarks, landmark_weights  # noqa: F401
    from hack_render.fit.photo import Photo, load_photo  # noqa: F401
    from hack_render.fit.stages import run_stage  # noqa: F401

    assert {"views", "beta", "psi", "alpha", "reports", "timings", "failures"} <= set(
        FitResult.__dataclass_fields__)
