"""Parameter sequences (format, round trips, errors that name the frame and the key), the
export CLI's bad-input handling (exit 2, one line, nothing written), turntable's motion as
a sequence, and the viewer's server (127.0.0.1, its own files only)."""

from __future__ import annotations

import json
import re
import urllib.error
import urllib.request

import numpy as np
import pytest
import torch

from hack_render.cli import main
from hack_render.errors import HackError
from hack_render.geometry.params import ParamSequence, load_sequence, save_sequence
from hack_render.render import turntable as tt


def _seq(frames=5, psi=True):
    rng = np.random.default_rng(3)
    return ParamSequence(fps=30.0, theta=rng.normal(0, 0.05, (frames, 8, 3)),
                         psi=rng.random((frames, 53)) if psi else None,
                         tau=rng.normal(0, 0.003, frames), global_orient=np.zeros((frames, 3)),
                         transl=rng.normal(0, 0.01, (frames, 3)))


@pytest.mark.parametrize("suffix", [".npz", ".jsonl"])
def test_sequence_round_trip(tmp_path, suffix):
    seq = _seq()
    back = load_sequence(save_sequence(tmp_path / f"s{suffix}", seq), 53)
    assert back.fps == 30.0 and back.frames == 5
    for key, arr in seq.arrays().items():
        np.testing.assert_array_equal(getattr(back, key), arr)  # JSON floats round-trip exactly


def test_sequence_missing_keys_stay_missing(tmp_path):
    seq = ParamSequence(fps=24.0, theta=np.zeros((3, 8, 3)))
    back = load_sequence(save_sequence(tmp_path / "s.jsonl", seq))
    assert back.psi is None and back.tau is None and back.theta.shape == (3, 8, 3)


def _jsonl(path, frames, header=None):
    lines = [json.dumps(header or {"format": "hack-sequence", "fps": 24})]
    lines += [json.dumps(f) for f in frames]
    path.write_text("\n".join(lines) + "\n")
    return path


def _frame(**kw):
    f = {"theta": np.zeros((8, 3)).tolist(), "tau": 0.0}
    f.update(kw)
    return f


@pytest.mark.parametrize("frames, match", [
    ([_frame(), _frame(), _frame(tau=float("nan"))], r"frame 2, key 'tau': contains NaN"),
    ([_frame(), {"theta": np.zeros((8, 3)).tolist()}], r"frame 1, key 'tau': missing"),
    ([_frame(), _frame(theta=np.zeros((7, 3)).tolist())], r"frame 1, key 'theta': expected 8 x 3"),
    ([_frame(), _frame(thetta=1.0)], r"frame 1, key 'thetta': unknown key"),
    ([_frame(psi=[0.1] * 53), _frame(psi=[0.1] * 52)], r"frame 1, key 'psi'"),
])
def test_jsonl_errors_name_frame_and_key(tmp_path, frames, match):
    with pytest.raises(HackError, match=match):
        load_sequence(_jsonl(tmp_path / "bad.jsonl", frames))


def test_npz_errors_name_frame_and_key(tmp_path):
    theta = np.zeros((4, 8, 3))
    theta[2, 5, 1] = np.inf
    np.savez(tmp_path / "a.npz", fps=24.0, theta=theta)
    with pytest.raises(HackError, match=r"frame 2, key 'theta': contains NaN or inf"):
        load_sequence(tmp_path / "a.npz")
    np.savez(tmp_path / "b.npz", theta=np.zeros((4, 8, 3)))
    with pytest.raises(HackError, match=r"key 'fps' is missing"):
        load_sequence(tmp_path / "b.npz")
    np.savez(tmp_path / "c.npz", fps=24.0, theta=np.zeros((4, 8, 3)), psi=np.zeros((4, 50)))
    with pytest.raises(HackError, match=r"key 'psi': expected 53 per frame"):
        load_sequence(tmp_path / "c.npz", 53)
    np.savez(tmp_path / "d.npz", fps=24.0, theta=np.zeros((4, 8, 3)), tau=np.zeros(3))
    with pytest.raises(HackError, match=r"key 'tau' has 3 frames, key 'theta' has 4"):
        load_sequence(tmp_path / "d.npz")


def test_turntable_motion_is_the_rendered_motion():
    """motion_sequence gives, frame by frame, the theta and tau turntable renders with."""
    from hack_render.geometry.skeleton import distribute_head_rotation

    spec = tt.TurntableSpec(8, look_around=True, swallow=True, fps=25)
    seq = tt.motion_sequence(spec)
    assert seq.fps == 25 and seq.frames == 8
    for i in (1, 5):
        ang = torch.deg2rad(torch.tensor(tt.head_angles_deg(spec.phase(i)), dtype=torch.float64))
        np.testing.assert_allclose(seq.theta[i], distribute_head_rotation(ang).numpy(), atol=1e-12)
        assert seq.tau[i] == tt.swallow_tau(spec.phase(i))


def run_cli(args, capsys) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exc:
        main(args)
    cap = capsys.readouterr()
    return exc.value.code, cap.out, cap.err


def _exit(args, capsys):
    try:
        code, out, err = run_cli(args, capsys)
    except pytest.fail.Exception:  # main returned without SystemExit: success
        cap = capsys.readouterr()
        return 0, cap.out, cap.err
    return code, out, err


@pytest.mark.parametrize("case", ["nan_frame", "unwritable", "suffix", "params_key", "influences",
                                  "psi_length"])
def test_export_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, case):
    out = tmp_path / "o" / "person.glb"
    args = ["export", "-o", str(out)]
    if case == "nan_frame":
        seq = _jsonl(tmp_path / "s.jsonl", [_frame(), _frame(), _frame(), _frame(tau=float("nan"))])
        args += ["--sequence", str(seq)]
        want = "frame 3, key 'tau'"
    elif case == "unwritable":
        (tmp_path / "blocker").write_text("a file, not a folder")
        out = tmp_path / "blocker" / "person.glb"
        args = ["export", "-o", str(out)]
        want = "blocker"
    elif case == "suffix":
        out = tmp_path / "person.fbx"
        args = ["export", "-o", str(out)]
        want = "expected a .glb, .gltf, .obj or .ply"
    elif case == "params_key":
        (tmp_path / "p.json").write_text(json.dumps({"betta": [1.0]}))
        args += ["--params", str(tmp_path / "p.json")]
        want = "unknown keys ['betta']"
    elif case == "influences":
        args += ["--influences", "6"]
        want = "--influences"
    else:
        np.savez(tmp_path / "s.npz", fps=24.0, theta=np.zeros((2, 8, 3)), psi=np.zeros((2, 40)))
        args += ["--sequence", str(tmp_path / "s.npz")]
        want = "key 'psi'"
    code, _, err = run_cli(args, capsys)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and want in lines[0] and "Traceback" not in err, err
    assert not out.exists() and not list(tmp_path.rglob("*.glb"))
    assert not list(tmp_path.rglob(".*tmp"))


def test_export_cli_writes_glb_and_reports(tmp_path, capsys):
    seq = save_sequence(tmp_path / "s.npz", _seq(3))
    out = tmp_path / "person.glb"
    main_ok = None
    try:
        main(["export", "-o", str(out), "--sequence", str(seq), "--expr", "AU12=0.5",
              "--alpha", "0.5,-0.5"])
    except SystemExit as exc:  # pragma: no cover - a failure
        main_ok = exc.code
    cap = capsys.readouterr()
    assert main_ok is None, cap.err
    assert out.read_bytes()[:4] == b"glTF"
    assert "224 morph targets, 3 animation frames" in cap.out  # 53 + 1 + 40 + 120 + 10
    assert "4 weights per vertex" in cap.out and " mm" in cap.out


def test_export_cli_obj_writes_mtl_and_maps(tmp_path, capsys):
    from hack_render.geometry import load_default_model
    from hack_render.geometry.obj_io import read_obj

    out = tmp_path / "person.obj"
    main(["export", "-o", str(out), "--beta", "1,-1"])
    assert (tmp_path / "person.mtl").is_file()
    assert (tmp_path / "person_maps" / "diffuse.png").is_file()
    assert "map_Kd -s 0.5 1 1 person_maps/diffuse.png" in (tmp_path / "person.mtl").read_text()
    assert read_obj(out).vertices.shape == (load_default_model().num_vertices, 3)


def _minimal_glb(path, doc=None, binary=b"", version=2):
    """A .glb of a glTF JSON document (default: just the asset) and a BIN chunk."""
    import struct

    js = json.dumps({"asset": {"version": "2.0"}} if doc is None else doc).encode()
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if binary:
        chunks += struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(b"glTF" + struct.pack("<II", version, 12 + len(chunks)) + chunks)
    return path


def test_viewer_serves_only_its_own_files(tmp_path):
    from hack_render.export.viewer import routes, start

    glb = _minimal_glb(tmp_path / "p.glb")
    (tmp_path / "secret.txt").write_text("not for the page")
    assert set(routes(glb)) == {"/", "/index.html", "/viewer.js", "/three.bundle.min.js",
                                "/LICENSE-three.js.txt", "/model.glb", "/config.json"}
    server, url = start(glb, 0)
    try:
        assert url.startswith("http://127.0.0.1:")
        assert server.server_address[0] == "127.0.0.1"
        with urllib.request.urlopen(url + "model.glb", timeout=10) as r:
            assert r.read()[:4] == b"glTF"
        with urllib.request.urlopen(url, timeout=10) as r:
            page = r.read().decode()
        assert "three.bundle.min.js" in page and "http" not in page.split("<body>")[0].replace(
            'charset="utf-8"', "")  # nothing fetched from the network
        for bad in ("secret.txt", "../secret.txt", "%2e%2e/secret.txt", "p.glb", "etc/passwd"):
            with pytest.raises(urllib.error.HTTPError) as exc:
                urllib.request.urlopen(url + bad, timeout=10)
            assert exc.value.code == 404
    finally:
        server.shutdown()


def test_view_bad_file_exits_2(tmp_path, capsys):
    code, _, err = run_cli(["view", str(tmp_path / "none.glb"), "--no-open"], capsys)
    assert code == 2 and "file not found" in err


def test_view_checks_the_file_before_serving(tmp_path):
    """`view` served an empty, truncated or non-glTF file and never said a word: the page
    showed nothing (issue 65). Now each is refused before a server starts, saying what
    is wrong; whole files (and a .gltf with its .bin) pass."""
    from hack_render.export.viewer import check_model

    doc = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": 8}]}
    whole = _minimal_glb(tmp_path / "whole.glb", doc, bytes(8)).read_bytes()
    assert check_model(tmp_path / "whole.glb")["asset"] == {"version": "2.0"}
    cases = {
        "empty.glb": (b"", "found an empty file"),
        "cut.glb": (whole[:-6], f"declares {len(whole)} bytes but the file holds {len(whole) - 6}"),
        "header.glb": (whole[:8], "expected a 12-byte header"),
        "text.glb": (b"not really a glb", "a .glb starts with b'glTF'"),
        "v1.glb": (whole[:4] + (1).to_bytes(4, "little") + whole[8:], "version 2, found version 1"),
        "nobin.glb": (_minimal_glb(tmp_path / "x.glb", doc).read_bytes(),
                      "buffer 0 expects 8 bytes in the file's BIN chunk, found none"),
        "noasset.glb": (_minimal_glb(tmp_path / "y.glb", {"scenes": []}).read_bytes(),
                        "'asset' object"),
        "list.gltf": (b"[1, 2]", "found an array"),
        "empty.gltf": (b"", "expected glTF JSON, found an empty file"),
        "lonely.gltf": (json.dumps(dict(doc, buffers=[{"byteLength": 8, "uri": "l.bin"}]))
                        .encode(), "l.bin, found no such file"),
    }
    for name, (data, match) in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(HackError, match=re.escape(match)):
            check_model(tmp_path / name)
    (tmp_path / "l.bin").write_bytes(bytes(8))
    assert check_model(tmp_path / "lonely.gltf")["buffers"][0]["uri"] == "l.bin"
