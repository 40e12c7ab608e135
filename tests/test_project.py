"""Project-level invariants: CI runs the README's test command; the CLI maps errors to exit 2."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import trimesh

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, flags=re.DOTALL)
    test_cmd = next(b for b in blocks if "pytest" in b)
    ci = (ROOT / ".ci" / "run").read_text()
    assert test_cmd.strip() in ci


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "hack_render.cli", *args], check=False,
                          capture_output=True, text=True, cwd=cwd)


def test_mesh_command_writes_obj_and_ply_with_uvs(tmp_path, cli_in_process):
    _cli = cli_in_process
    out = tmp_path / "m.obj"
    res = _cli("mesh", "-o", str(out), "--expr", "AU12=0.5", "--head-rotation", "0,30,0", "--both")
    assert res.returncode == 0, res.stderr
    obj = trimesh.load(out, process=False)
    ply = trimesh.load(out.with_suffix(".ply"), process=False)
    assert len(obj.faces) == len(ply.faces) == 52220
    assert obj.visual.uv is not None and obj.visual.uv.shape[0] == len(obj.vertices)
    assert abs(obj.vertices[:, 1].max() - ply.vertices[:, 1].max()) < 1e-6


def test_cli_bad_input_exits_2(tmp_path, cli_in_process):
    _cli = cli_in_process
    res = _cli("mesh", "-o", str(tmp_path / "x.obj"), "--expr", "AU99=1")
    assert res.returncode == 2 and "unknown action unit" in res.stderr
    bad = tmp_path / "p.json"
    bad.write_text('{"beta": [1.0, NaN]}')
    res = _cli("mesh", "-o", str(tmp_path / "x.obj"), "--params", str(bad))
    assert res.returncode == 2 and "beta" in res.stderr and "Traceback" not in res.stderr
    bad.write_text('{"betas": [1.0]}')
    res = _cli("mesh", "-o", str(tmp_path / "x.obj"), "--params", str(bad))
    assert res.returncode == 2 and "unknown keys ['betas']" in res.stderr
    res = _cli("model", "info", str(tmp_path / "missing.npz"))
    assert res.returncode == 2 and "not found" in res.stderr
    # a misspelt option or a missing value: click's usage message, exit 2, no traceback
    for args in (("fit", "photo.png", "-o", str(tmp_path / "f"), "--resolutions", "64"),
                 ("mesh", "-o")):
        res = _cli(*args)
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
        assert "Error:" in res.stderr and ("No such option: --resolutions" in res.stderr
                                           or "'-o' requires an argument" in res.stderr), res.stderr
    assert not (tmp_path / "x.obj").exists()


def test_theta_beyond_limits_policy(tmp_path, cli_in_process):
    _cli = cli_in_process
    p = tmp_path / "p.yaml"
    p.write_text("theta: [[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,1.2,0],[0,0,0]]\n")
    res = _cli("mesh", "-o", str(tmp_path / "a.obj"), "--params", str(p), "--limits", "error")
    # the message names the joint, the axis and the value (wording: geometry/limits.py)
    assert res.returncode == 2 and re.search(r"c1-c2 .*y.*68\.8", res.stderr), res.stderr
    res = _cli("mesh", "-o", str(tmp_path / "b.obj"), "--params", str(p), "--limits", "clamp")
    assert res.returncode == 0


def test_every_command_has_working_help():
    """`--help` teaches on every command and sub-command (and never crashes)."""
    from hack_render.cli import load_commands, main

    def walk(cmd, path):
        yield path
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from walk(sub, path + [name])

    paths = [[]] + [p for n, c in load_commands().items() for p in walk(c, [n])]
    assert len(paths) >= 8
    for path in paths:
        try:
            main(path + ["--help"])
        except SystemExit as exit_:
            assert exit_.code in (0, None), path
