"""`hack-render drive`: Live Link Face / ARKit CSVs and head rotation files to parameter
sequences (issue 24, part 2): the column mapping, the head's rotation over the joints, the
frame rate from timecodes, the export of the result, and bad files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from hack_render.cli import app
from hack_render.motion.drive import ARKIT, EYES, HEAD, model_name

FPS = 30


def _write_llf(path, frames=45, fps=FPS, extra_header=(), drop=()):
    """A CSV in Live Link Face's layout: Timecode, BlendShapeCount, 52 shapes, head, eyes."""
    header = ["Timecode", "BlendShapeCount", *ARKIT, *HEAD, *EYES, *extra_header]
    header = [h for h in header if h not in drop]
    rows = []
    for i in range(frames):
        s, f = divmod(i, fps)
        vals = {"Timecode": f"13:22:{5 + s:02d}:{f:02d}.{i % 7}00", "BlendShapeCount": "61"}
        for k, a in enumerate(ARKIT):
            vals[a] = f"{0.5 * (1 + np.sin(0.2 * i + k)) * 0.9:.4f}"
        vals.update({"HeadYaw": f"{0.3 * np.sin(0.1 * i):.5f}", "HeadPitch": f"{0.1:.5f}",
                     "HeadRoll": f"{-0.05:.5f}"})
        for e in EYES:
            vals[e] = "0.0"
        for h in extra_header:
            vals[h] = "1"
        rows.append(",".join(vals[h] for h in header))
    path.write_text(",".join(header) + "\n" + "\n".join(rows) + "\n")
    return path


def test_arkit_names_map_onto_the_models_expressions():
    from hack_render.geometry import load_default_model

    names = set(load_default_model().expression_names)
    mapped = [n for a in ARKIT for n in model_name(a)]
    assert set(mapped) == names  # every model shape is driven, by exactly one column
    assert len(mapped) == len(set(mapped)) == 53
    assert model_name("MouthSmileLeft") == ["mouthSmile_L"]
    assert model_name("CheekPuff") == ["cheekPuff_L", "cheekPuff_R"]
    assert model_name("TongueOut") == []


def test_live_link_csv_drives_psi_theta_and_fps(tmp_path):
    from hack_render.geometry import load_default_model
    from hack_render.geometry.params import load_sequence
    from hack_render.geometry.rotations import axis_angle_to_matrix, matrix_to_euler

    csv = _write_llf(tmp_path / "take.csv", extra_header=("Comment",))
    res = CliRunner().invoke(app, ["drive", str(csv), "-o", str(tmp_path / "take.npz")])
    assert res.exit_code == 0, res.output
    assert "45 frames at 30 fps" in res.output and "Comment" in res.output
    model = load_default_model()
    seq = load_sequence(tmp_path / "take.npz", model.num_expressions)
    assert seq.fps == FPS and seq.frames == 45
    names = model.expression_names
    raw = np.loadtxt(csv, delimiter=",", skiprows=1, usecols=range(2, 2 + 52))
    np.testing.assert_allclose(seq.psi[:, names.index("jawOpen")], raw[:, ARKIT.index("JawOpen")])
    for half in ("browInnerUp_L", "browInnerUp_R"):
        np.testing.assert_allclose(seq.psi[:, names.index(half)], raw[:, ARKIT.index("BrowInnerUp")])
    # the joints compose to the captured head rotation (within the neck's range)
    rot = axis_angle_to_matrix(torch.as_tensor(seq.theta))  # (T, 8, 3, 3)
    total = rot[:, 0]
    for k in range(1, 8):
        total = total @ rot[:, k]
    yaw = 0.3 * np.sin(0.1 * np.arange(45))
    R = total.numpy()
    fwd = R[:, :, 2]  # where the face looks
    np.testing.assert_allclose(np.arctan2(fwd[:, 0], fwd[:, 2]), yaw, atol=0.03)
    assert np.all(np.abs(matrix_to_euler(total).numpy()[:, 0] - 0.1) < 0.03)
    # export animates it
    res = CliRunner().invoke(app, ["export", "--sequence", str(tmp_path / "take.npz"), "-o",
                                   str(tmp_path / "take.glb")])
    assert res.exit_code == 0, res.output


def test_head_rotation_files(tmp_path):
    from hack_render.geometry.params import load_sequence

    np.save(tmp_path / "h.npy", np.tile([10.0, -5.0, 0.0], (12, 1)))
    res = CliRunner().invoke(app, ["drive", str(tmp_path / "h.npy"), "--degrees", "--fps", "24",
                                   "-o", str(tmp_path / "h.jsonl")])
    assert res.exit_code == 0, res.output
    seq = load_sequence(tmp_path / "h.jsonl")
    assert seq.fps == 24 and seq.frames == 12 and seq.psi is None
    # yaw is about y: the axial components carry it, summing to 10 degrees
    assert np.rad2deg(seq.theta[0, :, 1].sum()) == pytest.approx(10.0, abs=0.3)
    (tmp_path / "h.csv").write_text("time,yaw,pitch,roll\n0,0,0,0\n0.04,0.1,0,0\n0.08,0.2,0,0\n")
    res = CliRunner().invoke(app, ["drive", str(tmp_path / "h.csv"), "-o", str(tmp_path / "c.npz")])
    assert res.exit_code == 0 and "25 fps" in res.output, res.output


@pytest.mark.parametrize("case", ["missing-column", "nan", "bad-timecode", "short-row",
                                  "decreasing-time", "no-fps", "wrong-npy"])
def test_bad_captures_exit_2_with_the_reason(tmp_path, case, capsys):
    from hack_render.cli import main

    p = tmp_path / "c.csv"
    if case == "missing-column":
        _write_llf(p, drop=("JawOpen",))
        want = "JawOpen"
    elif case == "nan":
        _write_llf(p)
        lines = p.read_text().splitlines()
        cells = lines[3].split(",")
        cells[5] = "nan"
        lines[3] = ",".join(cells)
        p.write_text("\n".join(lines))
        want = "row 4"
    elif case == "bad-timecode":
        _write_llf(p)
        p.write_text(p.read_text().replace("13:22:05:03", "13-22-05-03", 1))
        want = "timecode"
    elif case == "short-row":
        _write_llf(p)
        p.write_text(p.read_text() + "13:22:09:00.000,61,0.1\n")
        want = "fields"
    elif case == "decreasing-time":
        p.write_text("time,yaw,pitch,roll\n0,0,0,0\n0.1,0,0,0\n0.05,0,0,0\n")
        want = "time column"
    elif case == "no-fps":
        _write_llf(p, frames=10)
        want = "--fps"
    else:
        p = tmp_path / "c.npy"
        np.save(p, np.zeros((5, 2)))
        want = "(T, 3)"
    out = tmp_path / "o.npz"
    with pytest.raises(SystemExit) as exc:
        main(["drive", str(p), "-o", str(out)])
    assert exc.value.code == 2
    assert not out.exists()
    err = capsys.readouterr().err
    assert want in err and "Traceback" not in err, err
