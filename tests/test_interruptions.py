"""Every interruption honest (issue 29): Ctrl-C exits 130 with one line saying what was
kept and how to resume; resumable commands (turntable, dataset, fit) resume to the
uninterrupted result or refuse when their arguments changed; one writer per folder; a
full disk is a clean exit 2 with nothing corrupted.

Real processes are killed (SIGKILL, SIGINT) at seeded points of tiny runs; the rest runs
in-process (``hack_render.cli.main``).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hack_render.cli import main
from hack_render.io import temp_glob

TT = ["turntable", "--frames", "10", "--resolution", "16", "--spp", "1", "--look-around",
      "--formats", "frames,gif", "--quiet"]
#: without hair (as tests/test_dataset.py's TINY: a scene built around each sample's groom
#: is most of a sample's time); the strands' order-free samples are
#: tests/test_dataset_hair.py's test_hair_samples_do_not_depend_on_order
DS_CONFIG = ("render: {resolution: 16, spp: 1, soft_mask_samples: 0}\n"
             "appearance: {height: 16, source: constant}\nlighting: {presets: [studio]}\n"
             "hair: none\n")
#: Where the processes are killed: after this many frames / samples (seeded, so a failure
#: reproduces).
POINTS = np.random.default_rng(29).integers(1, 6, size=4).tolist()


def run(args, capsys=None):
    """(exit code, stderr) of an in-process run."""
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = exc.code
    return code, (capsys.readouterr().err if capsys is not None else "")


def tree(folder: Path, skip=()) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in skip}


@contextlib.contextmanager
def ctrl_c_for_children():
    """Children started inside get Ctrl-C's default handling, as from a terminal. A suite
    started in the background by a non-interactive shell (as CI runs it) has SIGINT
    ignored, and an ignored signal stays ignored through exec (``start_new_session``,
    ``process_group`` and ``restore_signals`` leave it so), while a handled one is reset
    to the default there: so the test process handles SIGINT while it starts the child,
    instead of a ``preexec_fn`` (unsafe with threads, ruff PLW1509). (``hack_render.cli``'s
    main installs its own handlers whatever it inherits; this keeps the child a terminal's
    until then.)"""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def spawn(args) -> subprocess.Popen:
    with ctrl_c_for_children():
        return subprocess.Popen([sys.executable, "-m", "hack_render.cli", *map(str, args)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)


def kill_when(proc: subprocess.Popen, ready, sig: int, timeout: float = 240.0) -> tuple[int, str]:
    """Send ``sig`` once ``ready()`` holds (or the process ended); (exit code, stderr)."""
    deadline = time.time() + timeout
    while not ready() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    if proc.poll() is None:
        os.kill(proc.pid, sig)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


@pytest.fixture(scope="module")
def turntable_reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("tt") / "ref"
    assert run(TT + ["-o", out])[0] == 0
    return out


# --- turntable -------------------------------------------------------------------------------
@pytest.mark.parametrize("sig, point", [
    pytest.param(signal.SIGKILL, POINTS[0], marks=pytest.mark.slow),  # more in the slow run
    (signal.SIGINT, POINTS[1])], ids=["SIGKILL", "SIGINT"])
def test_turntable_killed_then_resumed_is_byte_identical(turntable_reference, tmp_path, sig,
                                                         point, capsys):
    out = tmp_path / "tt"
    frames = out / "frames"
    proc = spawn(TT + ["-o", out])
    code, err = kill_when(proc, lambda: frames.is_dir() and
                          len(list(frames.glob("frame_*.png"))) >= point, sig)
    if sig == signal.SIGINT and code != 0:  # 0: it finished before the signal came
        assert code == 130, err
        last = err.strip().splitlines()[-1]
        assert last.startswith("interrupted: kept ") and "--resume" in last, err
        assert "Traceback" not in err
    elif sig == signal.SIGKILL:
        assert code in (-signal.SIGKILL, 0)
    record = json.loads((out / "turntable.json").read_text())
    assert record["complete"] is (code == 0)
    # a kill between two writes leaves a temporary: resume removes it
    (frames / ".tmp-0a1b2c-abc123xy.png").write_bytes(b"half")
    (frames / ".frame_0009.abc123.png").write_bytes(b"half")  # as older versions named it
    # killed while encoding
    (out / temp_glob("turntable.gif").replace("*", "x7k2q9zz.gif")).write_bytes(b"GIF89a half")
    assert run(TT + ["-o", out, "--resume"])[0] == 0
    assert json.loads((out / "turntable.json").read_text())["complete"] is True
    assert tree(out) == tree(turntable_reference)  # frames, GIF, cameras and the record


@pytest.mark.parametrize("missing", [
    [2, 3, 4, 5, 6, 7, 8, 9], [0, 4, 8],
    pytest.param([3, 4, 5, 6, 7, 8, 9], marks=pytest.mark.slow),
    pytest.param([9], marks=pytest.mark.slow)], ids=["from-2", "holes", "from-3", "last"])
def test_turntable_resumed_from_any_frame_is_byte_identical(turntable_reference, tmp_path,
                                                            missing):
    """Mitsuba's state after an update depends on the updates before it (a run started at
    frame 2 or 3 differed in frames 8 and 9 by up to 6/255): a resume replays them."""
    import shutil

    out = tmp_path / "tt"
    shutil.copytree(turntable_reference, out)
    for i in missing:
        (out / "frames" / f"frame_{i:04d}.png").unlink()
    assert run(TT + ["-o", out, "--resume"])[0] == 0
    assert tree(out) == tree(turntable_reference)


def test_turntable_resume_with_other_arguments_is_refused(turntable_reference, tmp_path,
                                                          capsys):
    import shutil

    out = tmp_path / "tt"
    shutil.copytree(turntable_reference, out)
    before = tree(out)
    for change in (["--resolution", "24"], ["--beta", "1.0"], ["--spp", "2"]):
        # Click keeps the last value of a repeated option: the change overrides TT's
        code, err = run(TT + change + ["-o", out, "--resume"], capsys)
        assert code == 2 and "--resume" in err and change[0].lstrip("-") in err, err
    assert tree(out) == before  # nothing touched


def test_turntable_frames_without_a_record_are_not_resumed(turntable_reference, tmp_path,
                                                           capsys):
    import shutil

    out = tmp_path / "tt"
    shutil.copytree(turntable_reference / "frames", out / "frames")
    code, err = run(TT + ["-o", out, "--resume"], capsys)
    assert code == 2 and "turntable.json" in err


def test_two_writers_on_one_folder(tmp_path, capsys):
    from hack_render import boundary

    out = tmp_path / "tt"
    with boundary.folder_lock(out):
        code, err = run(TT + ["-o", out], capsys)
    assert code == 2 and f"pid {os.getpid()}" in err and "another hack-render run" in err
    assert not (out / ".hack-render.lock").exists()  # released and removed


def test_a_killed_runs_lock_file_does_not_block(tmp_path, capsys):
    """flock ends with its process: a lock file left by a SIGKILL is taken over."""
    out = tmp_path / "tt"
    out.mkdir()
    (out / ".hack-render.lock").write_text("pid 99999")
    from hack_render import boundary

    with boundary.folder_lock(out) as path:
        assert path.read_text() == f"pid {os.getpid()}"
    assert not path.exists()


def test_disk_full_while_rendering_frames(tmp_path, capsys, monkeypatch):
    import imageio.v3 as iio

    real, calls = iio.imwrite, []

    def full(path, *a, **k):
        calls.append(path)
        if len(calls) == 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, *a, **k)

    monkeypatch.setattr(iio, "imwrite", full)
    out = tmp_path / "tt"
    code, err = run(TT + ["-o", out], capsys)
    assert code == 2 and "no space left" in err and "Traceback" not in err
    assert len([ln for ln in err.splitlines() if ln.startswith("error:")]) == 1
    assert sorted(p.name for p in (out / "frames").iterdir()) == [
        "frame_0000.png", "frame_0001.png"]  # complete frames kept, no temporary
    assert json.loads((out / "turntable.json").read_text())["complete"] is False


@pytest.mark.parametrize("command", ["mesh", "render"])
def test_disk_full_in_mesh_and_render(tmp_path, capsys, monkeypatch, command):
    import os as os_

    real = os_.replace

    def full(src, dst, *a, **k):  # the rename that would complete the file
        raise OSError(errno.ENOSPC, "No space left on device", str(dst))

    monkeypatch.setattr(os_, "replace", full)
    out = tmp_path / ("x.obj" if command == "mesh" else "x.png")
    args = [command, "-o", out] + ([] if command == "mesh" else ["--resolution", "16",
                                                                  "--spp", "1"])
    code, err = run(args, capsys)
    monkeypatch.setattr(os_, "replace", real)
    errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert code == 2 and len(errors) == 1 and "no space left" in errors[0].lower()
    assert "Traceback" not in err
    assert not list(tmp_path.rglob("*.*"))  # no output, no temporary


# --- Ctrl-C in-process: exit 130 and the line ------------------------------------------------
def test_ctrl_c_in_render_exits_130_with_a_line(tmp_path, capsys, monkeypatch):
    from hack_render.render import scene

    def interrupted(self, *a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(scene.HeadScene, "render", interrupted)
    code, err = run(["render", "-o", tmp_path / "x.png", "--resolution", "16", "--spp", "1"],
                    capsys)
    assert code == 130
    assert err.strip().splitlines()[-1].startswith("interrupted: kept 0 finished image(s)")
    assert not list(tmp_path.iterdir())


def _drjit_loop_interrupted():
    """What Ctrl-C inside a Dr.Jit loop surfaces as: dr.while_loop() re-raises the
    KeyboardInterrupt its body met as a RuntimeError (issue 65)."""
    import drjit as dr
    import mitsuba as mi

    from hack_render.render.engine import ensure_variant

    ensure_variant()

    def body(i):
        raise KeyboardInterrupt

    dr.while_loop(state=(mi.Int32(0),), cond=lambda i: i < 3, body=body)


def test_ctrl_c_inside_a_drjit_loop_exits_130_with_the_line(tmp_path, capsys, monkeypatch):
    from hack_render.render import scene

    monkeypatch.setattr(scene.HeadScene, "render", lambda self, *a, **k: _drjit_loop_interrupted())
    code, err = run(["render", "-o", tmp_path / "x.png", "--resolution", "16", "--spp", "1"],
                    capsys)
    assert code == 130, err
    assert "Traceback" not in err and "RuntimeError" not in err
    assert err.strip().splitlines()[-1].startswith("interrupted: kept 0 finished image(s)")


def test_sigterm_that_surfaces_as_another_error_exits_143(tmp_path, capsys, monkeypatch):
    """SIGTERM during a native import or loop can come out as an ImportError or a
    RuntimeError with no KeyboardInterrupt in its chain: once the signal was received the
    interruption wins (143, the kept-work line, no traceback)."""
    import os
    import signal

    from hack_render.geometry import obj_io

    def terminated_in_native_code(*a, **k):
        os.kill(os.getpid(), signal.SIGTERM)  # the handler raises KeyboardInterrupt here
        raise AssertionError("not reached")

    def wrapped(*a, **k):
        try:
            terminated_in_native_code()
        except KeyboardInterrupt:
            pass  # a native layer that swallows it and fails otherwise
        raise ImportError("initialization failed")

    monkeypatch.setattr(obj_io, "write_mesh", wrapped)
    code, err = run(["mesh", "-o", tmp_path / "x.obj"], capsys)
    assert code == 143, err
    assert err.strip().splitlines()[-1].startswith("terminated (SIGTERM): ")
    assert "Traceback" not in err and not list(tmp_path.iterdir())


def test_ctrl_c_in_mesh_exits_130(tmp_path, capsys, monkeypatch):
    from hack_render.geometry import obj_io

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(obj_io, "write_mesh", interrupted)
    code, err = run(["mesh", "-o", tmp_path / "x.obj"], capsys)
    assert code == 130 and err.strip().splitlines()[-1].startswith(
        "interrupted: no file was left half-written")
    assert not list(tmp_path.iterdir())


def test_fit_interrupted_while_writing_is_marked_incomplete(tmp_path, capsys, monkeypatch):
    """The fit is done, its files half written: fit_run.json says complete: false; a fit
    interrupted before writing leaves nothing."""
    from hack_render.fit import cli as fit_cli
    from hack_render.fit import outputs

    photo = tmp_path / "face.png"
    import imageio.v3 as iio

    iio.imwrite(photo, np.full((32, 32, 3), 100, np.uint8))

    def fitting_interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(fit_cli, "_fit", fitting_interrupted)
    code, err = run(["fit", photo, "-o", tmp_path / "f", "--quiet"], capsys)
    assert code == 130 and "nothing was written" in err and not (tmp_path / "f").exists()

    monkeypatch.setattr(fit_cli, "_fit", lambda *a, **k: object())

    def half_written(res, outdir, extra=None):
        (outdir / "params.json").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "write_all", half_written)
    code, err = run(["fit", photo, "-o", tmp_path / "f", "--quiet"], capsys)
    assert code == 130 and "incomplete" in err.strip().splitlines()[-1]
    record = json.loads((tmp_path / "f" / "fit_run.json").read_text())
    assert record["complete"] is False and record["command"] == "fit"


def test_fit_resume_skips_a_complete_fit_and_refuses_other_inputs(tmp_path, capsys,
                                                                  monkeypatch):
    import imageio.v3 as iio

    from hack_render.fit import cli as fit_cli
    from hack_render.fit import outputs

    photo = tmp_path / "face.png"
    iio.imwrite(photo, np.full((32, 32, 3), 100, np.uint8))
    monkeypatch.setattr(fit_cli, "_fit", lambda *a, **k: object())

    def write_all(res, outdir, extra=None):
        (outdir / "params.json").write_text("{}")
        return [outdir / "params.json"]

    monkeypatch.setattr(outputs, "write_all", write_all)
    out = tmp_path / "f"
    assert fit_cli.fit_photos([photo], out, progress=False)[1][-1] == out / "fit_run.json"
    assert json.loads((out / "fit_run.json").read_text())["complete"] is True

    def must_not_fit(*a, **k):
        raise AssertionError("a complete fit was redone")

    monkeypatch.setattr(fit_cli, "_fit", must_not_fit)
    code, err = run(["fit", photo, "-o", out, "--resume", "--quiet"], capsys)
    assert code == 0
    iio.imwrite(photo, np.full((32, 32, 3), 200, np.uint8))  # another photo, same name
    code, err = run(["fit", photo, "-o", out, "--resume", "--quiet"], capsys)
    assert code == 2 and "--resume" in err and "photos" in err


# --- dataset -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def dataset_reference(tmp_path_factory):
    base = tmp_path_factory.mktemp("ds")
    (base / "cfg.yaml").write_text(DS_CONFIG)
    out = base / "ref"
    assert run(["dataset", "--n", 4, "-o", out, "--config", base / "cfg.yaml", "--quiet"])[0] == 0
    # no stray folders (samples/x, manifest/x), no lock left, the shard marked complete
    assert sorted(p.name for p in (out / "samples").iterdir()) == [f"{i:07d}" for i in range(4)]
    assert sorted(p.name for p in (out / "manifest").iterdir()) == [
        "shard-000-of-001.complete.json", "shard-000-of-001.jsonl"]
    return out, base / "cfg.yaml"


def test_dataset_sigint_exits_130_then_resume_is_byte_identical(dataset_reference, tmp_path):
    ref, cfg = dataset_reference
    out = tmp_path / "ds"
    point = POINTS[2] % 3 + 1
    proc = spawn(["dataset", "--n", 4, "-o", out, "--config", cfg, "--quiet"])
    code, err = kill_when(proc, lambda: len(list(out.glob("samples/*/sample.json"))) >= point,
                          signal.SIGINT)
    if code != 0:
        assert code == 130, err
        last = err.strip().splitlines()[-1]
        assert last.startswith("interrupted: kept ") and "--resume" in last, err
        assert not (out / "manifest" / "shard-000-of-001.complete.json").exists()
        # every manifest line is whole and names a complete sample
        for line in (out / "manifest" / "shard-000-of-001.jsonl").read_text().splitlines():
            rec = json.loads(line)
            assert (out / "samples" / f"{rec['index']:07d}" / "sample.json").is_file()
    assert run(["dataset", "--n", 4, "-o", out, "--config", cfg, "--quiet", "--resume"])[0] == 0
    assert tree(out) == tree(ref)


@pytest.mark.slow
def test_dataset_sigterm_exits_143_with_the_line(dataset_reference, tmp_path):
    """A scheduler's SIGTERM (Slurm's time limit) is an interruption too: the queued
    samples are completed, the line says what was kept, the exit code is 128 + 15."""
    _, cfg = dataset_reference
    out = tmp_path / "ds"
    proc = spawn(["dataset", "--n", 4, "-o", out, "--config", cfg, "--quiet"])
    code, err = kill_when(proc, lambda: len(list(out.glob("samples/*/sample.json"))) >= 1,
                          signal.SIGTERM)
    if code != 0:
        assert code == 143, err
        last = err.strip().splitlines()[-1]
        assert last.startswith("terminated (SIGTERM): kept ") and "--resume" in last, err


def test_dataset_rerun_over_complete_folder_without_resume_is_refused(dataset_reference,
                                                                      capsys):
    ref, cfg = dataset_reference
    before = tree(ref)
    code, err = run(["dataset", "--n", 4, "-o", ref, "--config", cfg, "--quiet"], capsys)
    assert code == 2 and "--resume" in err
    assert tree(ref) == before


def test_dataset_disk_full_keeps_whole_manifest_lines(dataset_reference, tmp_path, capsys,
                                                      monkeypatch):
    from hack_render.dataset import worker

    ref, cfg = dataset_reference
    real = worker._write_png

    def full(path, array):
        if "0000002" in str(path):
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, array)

    monkeypatch.setattr(worker, "_write_png", full)
    out = tmp_path / "ds"
    code, err = run(["dataset", "--n", 4, "-o", out, "--config", cfg, "--quiet"], capsys)
    assert code == 2 and "no space left" in err and "Traceback" not in err
    lines = (out / "manifest" / "shard-000-of-001.jsonl").read_text().splitlines()
    logged = [json.loads(x)["index"] for x in lines]  # whole lines, complete samples only
    assert {0, 1} <= set(logged) and 2 not in logged  # (3 too if it was already queued)
    assert all((out / "samples" / f"{i:07d}" / "sample.json").is_file() for i in logged)
    assert not (out / "samples" / "0000002" / "sample.json").exists()
    assert not (out / "manifest" / "shard-000-of-001.complete.json").exists()
    monkeypatch.setattr(worker, "_write_png", real)
    assert run(["dataset", "--n", 4, "-o", out, "--config", cfg, "--quiet", "--resume"])[0] == 0
    assert tree(out) == tree(ref)


def test_manifest_line_cut_by_a_full_disk_is_taken_back(tmp_path, monkeypatch):
    """The disk fills half-way through a manifest line: the line is removed, the earlier
    ones stay whole (a truncated line was left before)."""
    from hack_render.dataset import runner

    job = runner.Job(tmp_path, 3, 0, {})
    job.manifest_path.parent.mkdir(parents=True)
    runner._append_manifest(job, {"index": 0})
    real_open = open

    class HalfFull:
        def __init__(self, *a, **k):
            self.f = real_open(*a, **k)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def tell(self):
            return self.f.tell()

        def truncate(self, n):
            return self.f.truncate(n)

        def write(self, text):
            self.f.write(text[: len(text) // 2])
            self.f.flush()
            raise OSError(errno.ENOSPC, "No space left on device", str(job.manifest_path))

        def flush(self):
            self.f.flush()

    monkeypatch.setattr(runner, "open", HalfFull, raising=False)
    with pytest.raises(OSError, match="No space"):
        runner._append_manifest(job, {"index": 1, "files": {"a": 1}})
    assert job.manifest_path.read_text() == '{"index": 0}\n'


def test_two_dataset_writers_on_one_shard(dataset_reference, tmp_path, capsys):
    from hack_render import boundary

    _, cfg = dataset_reference
    out = tmp_path / "ds"
    with boundary.folder_lock(out / "manifest", ".lock.shard-000-of-001"):
        code, err = run(["dataset", "--n", 2, "-o", out, "--config", cfg, "--quiet"], capsys)
    assert code == 2 and "another hack-render run" in err


@pytest.mark.slow
@pytest.mark.parametrize("point", POINTS[2:])
def test_more_seeded_kill_points(turntable_reference, tmp_path, point):
    out = tmp_path / "tt"
    proc = spawn(TT + ["-o", out])
    kill_when(proc, lambda: len(list((out / "frames").glob("frame_*.png"))) >= point,
              signal.SIGKILL)
    assert run(TT + ["-o", out, "--resume"])[0] == 0
    assert tree(out) == tree(turntable_reference)
