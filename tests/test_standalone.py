"""The package stands on its own: nothing at run time reads a file outside the installed
package (or a path the user passes).

- 01 (fast): no module under ``hack_render/``, ``appearance/`` or ``scenes/`` names a path
  outside its package: no absolute path of any machine, no ``..`` segment, no development
  data folder, and no ``Path(__file__).parents[k]`` that climbs above the package root.
- 02 (slow, opt-in): the wheel, installed into a fresh virtual environment in a temporary
  folder outside the checkout, runs the main jobs at tiny settings (``render``,
  ``turntable``, ``dataset --n 1``, ``fit --no-photometric`` on skimage's astronaut) with no
  development data on any search path.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("hack_render", "appearance", "scenes")
# strings that locate files outside the package: an absolute path of some machine, a
# parent-directory segment, or the development data folder
_OUTSIDE = re.compile(r"^(/(work|home|root|opt|tmp|mnt|data|Users|srv|var)/)|(^|/)\.\.(/|$)|"
                      r"shared/data|ict-facekit/")


def _modules():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            yield pkg, path


def _parents_depth(node: ast.AST) -> int | None:
    """k for ``Path(__file__)....parents[k]`` (or the number of chained ``.parent``)."""
    if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute) \
            and node.value.attr == "parents" and isinstance(node.slice, ast.Constant) \
            and "__file__" in ast.unparse(node.value):
        return int(node.slice.value)
    if isinstance(node, ast.Attribute) and node.attr == "parent" \
            and "__file__" in ast.unparse(node):
        n, cur = 0, node
        while isinstance(cur, ast.Attribute) and cur.attr == "parent":
            n, cur = n + 1, cur.value
        return n - 1  # Path(f).parent is parents[0]
    return None


def test_01_no_module_names_a_path_outside_its_package():
    bad = []
    for pkg, path in _modules():
        tree = ast.parse(path.read_text(), filename=str(path))
        depth = len(path.relative_to(ROOT / pkg).parts) - 1  # folders below the package root
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                # docstrings and messages are prose; a path is one token without spaces
                for tok in node.value.split():
                    if _OUTSIDE.search(tok.strip("`'\"(),.;:")) and "://" not in tok:
                        bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {tok!r}")
            k = _parents_depth(node)
            if k is not None and k > depth:
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: climbs {k + 1} folders "
                           f"from a module {depth} below the package root")
    assert not bad, "paths outside the package:\n" + "\n".join(bad)


def test_01b_the_check_catches_what_it_should():
    """The scan above can fail: it flags the forms the old code used."""
    assert _OUTSIDE.search("/work/shared/data/ict-facekit/generic_neutral_mesh.obj")
    assert _OUTSIDE.search("../shared")
    assert not _OUTSIDE.search("data/hack_default.npz")
    old = ast.parse('Path(__file__).resolve().parents[1] / ".." / "shared"').body[0].value
    sub = next(n for n in ast.walk(old) if isinstance(n, ast.Subscript))
    assert _parents_depth(sub) == 1  # > 0, the depth of appearance/uv.py


def test_01c_package_data_is_declared_for_every_shipped_file():
    """Every data file the code reads at run time ships in the wheel (pyproject globs)."""
    import tomllib

    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]
    for pkg in PACKAGES:
        data = [p for p in (ROOT / pkg).rglob("*") if p.is_file() and "data" in p.parts
                and p.suffix != ".py" and "__pycache__" not in p.parts]
        for f in data:
            rel = f.relative_to(ROOT / pkg).as_posix()
            assert any(Path(rel).match(g) for g in globs.get(pkg, [])), \
                f"{pkg}/{rel} is not in [tool.setuptools.package-data]"


def _run(cmd, cwd, env, timeout=900):
    res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True,
                         timeout=timeout, check=False)
    assert res.returncode == 0, f"{cmd}: exit {res.returncode}\n{res.stdout[-3000:]}\n" \
                                f"{res.stderr[-3000:]}"
    return res


@pytest.mark.slow
def test_02_wheel_in_a_fresh_venv_runs_the_main_jobs(tmp_path):
    """~3 min: build the wheel, install it alone, run render, turntable, dataset and fit."""
    pytest.importorskip("dlib")
    work = tmp_path / "user"  # a user's folder: no checkout, no development data near it
    work.mkdir()
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
          "-w", str(tmp_path / "wheel"), str(ROOT)], tmp_path, os.environ.copy())
    wheel = next((tmp_path / "wheel").glob("hack_render-*.whl"))
    venv = tmp_path / "venv"
    # the dependencies (torch, mitsuba, ...) come from this interpreter's site-packages;
    # the package itself only from the wheel
    _run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], tmp_path,
         os.environ.copy())
    py, bindir = venv / "bin" / "python", venv / "bin"
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("HACK_", "PYTHON")) and k != "VIRTUAL_ENV"}
    env.update(PATH=f"{bindir}{os.pathsep}{env.get('PATH', '')}", PYTHONNOUSERSITE="1",
               MPLBACKEND="Agg")
    _run([str(py), "-m", "pip", "install", "--no-deps", "--force-reinstall", "-q", str(wheel)],
         work, env)
    probe = ("import hack_render, appearance, scenes, sys; "
             "print(hack_render.__file__, appearance.__file__, scenes.__file__); print(*sys.path)")
    where = _run([str(py), "-c", probe], work, env).stdout
    first, paths = where.splitlines()[0], where.splitlines()[1]
    for f in first.split():
        assert Path(f).is_relative_to(venv), f"imported from outside the venv: {f}"
    assert str(ROOT) not in paths.split()

    hr = str(bindir / "hack-render")
    _run([hr, "render", "-o", "r.png", "--resolution", "48", "--spp", "2"], work, env)
    _run([hr, "turntable", "-o", "tt", "--frames", "2", "--resolution", "48", "--spp", "2",
          "--formats", "gif"], work, env)
    (work / "tiny.yaml").write_text("render:\n  resolution: 48\n  spp: 2\n")
    _run([hr, "dataset", "--n", "1", "-o", "ds", "--config", "tiny.yaml"], work, env)
    photo = "import imageio.v3 as iio, skimage.data; iio.imwrite('astronaut.png', skimage.data.astronaut())"
    _run([str(py), "-c", photo], work, env)
    _run([hr, "fit", "astronaut.png", "-o", "fit", "--no-photometric", "--quiet"], work, env)

    assert (work / "r.png").stat().st_size > 0
    assert (work / "tt" / "turntable.gif").stat().st_size > 0
    assert list((work / "ds").rglob("*.png")), "the dataset wrote no image"
    assert (work / "fit" / "params.json").is_file()
    # and nothing of the development tree was touched or needed
    assert not any(p.name == "shared" for p in tmp_path.iterdir())
