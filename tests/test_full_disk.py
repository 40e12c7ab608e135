"""A full disk (issue 65): every command ends in one line and exit 2, and no output is
left incomplete under its final name. The commands write onto a real, small tmpfs (root
and `mount` needed; skipped elsewhere); the MP4 check also runs on a cut file."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import uuid
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest

from hack_render.errors import HackError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def tiny_disk(tmp_path):
    """A function (size) -> a folder on a tmpfs of that size, unmounted afterwards."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    mounted = []

    def make(size: str) -> Path:
        folder = tmp_path / f"disk-{uuid.uuid4().hex[:6]}"
        folder.mkdir()
        res = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs",
                              str(folder)], capture_output=True, text=True, check=False)
        if res.returncode:
            pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
        mounted.append(folder)
        return folder

    yield make
    for folder in mounted:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def cli(*args, cwd=None):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "hack_render.cli", *map(str, args)],
                          capture_output=True, text=True, check=False, env=env, cwd=cwd,
                          timeout=600)


def one_line_exit_2(res):
    assert res.returncode == 2, (res.returncode, res.stderr[-2000:])
    assert "Traceback" not in res.stderr, res.stderr[-2000:]
    assert res.stderr.strip().splitlines()[-1].startswith("error: "), res.stderr
    assert "no space left on the device" in res.stderr


def files(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*")
            if p.is_file()}


def test_exr_on_a_full_disk_is_an_os_error_and_leaves_nothing(tiny_disk):
    """OpenEXR writes an empty file and says nothing when the disk is full as it flushes:
    write_exr reads it back and raises ENOSPC; nothing is left."""
    from hack_render.io.image import write_exr

    disk = tiny_disk("8k")
    (disk / "fill").write_bytes(b"\0" * 4096)
    with pytest.raises(OSError) as err:
        for i in range(4):
            write_exr(disk / f"a{i}.exr", {"Z": np.random.default_rng(i).random((48, 48))})
    assert err.value.errno == 28 and str(disk) in err.value.filename
    assert all(size > 0 for size in files(disk).values()), files(disk)
    assert not [n for n in files(disk) if n.startswith(".tmp")]


def test_render_exr_and_appearance_sample_on_a_full_disk(tiny_disk):
    disk = tiny_disk("8k")
    res = cli("render", "-o", disk / "x.png", "--exr", disk / "x.exr", "--resolution", 64,
              "--spp", 4, "--denoise", "off")
    one_line_exit_2(res)
    assert "x.exr" not in files(disk) and all(s > 0 for s in files(disk).values())
    disk2 = tiny_disk("8k")
    res = cli("appearance", "sample", "-o", disk2 / "s", "--seed", 1)
    one_line_exit_2(res)
    assert all(s > 0 for s in files(disk2).values()), files(disk2)


def test_export_obj_on_a_full_disk_leaves_no_part(tiny_disk):
    """An OBJ, its .mtl and its maps are one output: none of them stays without the rest."""
    disk = tiny_disk("3m")
    res = cli("export", "-o", disk / "p.obj")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert "No space left on device" in res.stderr.splitlines()[-1]
    assert files(disk) == {} and not (disk / "p_maps").exists()


def test_dataset_on_a_full_disk_leaves_no_empty_file(tiny_disk):
    disk = tiny_disk("40k")
    cfg = disk.parent / "ds.yaml"
    cfg.write_text("render: {resolution: 32, spp: 1, soft_mask_samples: 0}\n"
                   "appearance: {height: 16, source: constant}\nlighting: {presets: [studio]}\n"
                   "hair: none\n")   # (the groom's scene: most of a sample's time)
    res = cli("dataset", "--n", 2, "-o", disk / "ds", "--config", cfg, "--quiet")
    one_line_exit_2(res)
    # the manifest starts empty (no sample complete yet: a valid, empty JSONL)
    empty = [n for n, s in files(disk).items() if s == 0 and not n.endswith(".jsonl")]
    assert empty == []


def test_an_mp4_without_its_index_is_never_kept(tmp_path, monkeypatch):
    """ffmpeg stopped by a full disk leaves an MP4 without its 'moov' index and may say
    nothing: write_mp4 checks the boxes; on an all but full disk that is ENOSPC, else an
    error naming the file; the temporary is removed either way."""
    from hack_render.render import video

    frames = [np.full((16, 16, 3), 40 * i, np.uint8) for i in range(6)]
    good = video.write_mp4(tmp_path / "good.mp4", frames, fps=6)
    kinds = [k for k, _ in video.mp4_boxes(good)]
    assert {"ftyp", "moov", "mdat"} <= set(kinds)
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    assert "mdat" not in {k for k, _ in video.mp4_boxes(cut)}  # runs past the end
    with pytest.raises(HackError, match="incomplete MP4"):
        video.check_mp4(cut, tmp_path / "turntable.mp4")
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(video.shutil, "disk_usage", lambda p: Usage(1, 1, 0))
    with pytest.raises(OSError) as err:
        video.check_mp4(cut, tmp_path / "turntable.mp4")
    assert err.value.errno == 28 and err.value.filename.endswith("turntable.mp4")
    video.check_mp4(good, tmp_path / "good.mp4")  # a whole file passes on a full disk too
