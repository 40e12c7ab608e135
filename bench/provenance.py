"""Where a benchmark result came from: commit, date, machine and command.

Every script in ``bench/`` that writes a result file writes it through
:func:`write_result`, so each ``bench/results/*.json`` says which code, on which machine,
by which command, made it. ``bench/make_benchmarks_page.py`` turns those files into the
docs' benchmarks page.

    from provenance import write_result      # bench/ is on sys.path when run as a script
    write_result("bench/results/fit_synthetic256.json", {"median": ...})

Scripts that report by printing wrap their run in :func:`recorded`, which keeps what they
print and writes it with the same fields (``--out``).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import io
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIELDS = ("commit", "date", "machine", "command")


def _git(*args: str) -> str:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                             timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def commit() -> str:
    """HEAD's hash, with ``-dirty`` when tracked files differ from it ('unknown' outside git)."""
    head = _git("rev-parse", "HEAD")
    if not head:
        return "unknown"
    return head + ("-dirty" if _git("status", "--porcelain", "--untracked-files=no") else "")


def machine() -> str:
    """CPU count and model, OS, Python, and the GPU when torch sees one."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    text = f"{os.cpu_count()} CPUs ({cpu}), {platform.system()} {platform.release()}, " \
           f"Python {platform.python_version()}"
    if "torch" in sys.modules:
        torch = sys.modules["torch"]
        text += f", torch {torch.__version__}"
        if torch.cuda.is_available():
            text += f", GPU {torch.cuda.get_device_name(0)}"
    return text


def provenance(argv: list[str] | None = None) -> dict:
    """The four fields every result file carries; ``argv`` defaults to this process's."""
    argv = sys.argv if argv is None else argv
    return {"commit": commit(),
            "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "machine": machine(),
            "command": "python " + " ".join(shlex.quote(a) for a in argv)}


def write_result(path: str | os.PathLike, data: dict, argv: list[str] | None = None) -> Path:
    """Write ``data`` as JSON with the provenance fields first (atomically: a temporary
    name, then a rename, so an interrupted run never leaves half a file)."""
    path = Path(path)
    out = {**provenance(argv), **{k: v for k, v in data.items() if k not in FIELDS}}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(out, indent=1) + "\n")
    tmp.replace(path)
    return path


class _Tee(io.TextIOBase):
    def __init__(self, *streams):
        self.streams = streams

    def write(self, text):
        for stream in self.streams:
            stream.write(text)
        return len(text)

    def flush(self):
        for stream in self.streams:
            stream.flush()


@contextlib.contextmanager
def recorded(path: str | os.PathLike | None, title: str, argv: list[str] | None = None):
    """Run the ``with`` body printing as usual; when ``path`` is given and the body ends
    without an error, write what it printed (``"printed"``: a list of lines) under
    ``title`` with the provenance fields."""
    if path is None:
        yield
        return
    buf = io.StringIO()
    stdout = sys.stdout
    sys.stdout = _Tee(stdout, buf)
    try:
        yield
    finally:
        sys.stdout = stdout
    write_result(path, {"title": title, "printed": buf.getvalue().splitlines()}, argv)
