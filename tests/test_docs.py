"""Documentation invariants: a short self-contained README, a docs site that builds with
`mkdocs build --strict`, and benchmark results that say where they came from."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench_module(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_readme_is_short_and_links_stay_in_the_repository():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert targets, "the README links its pictures and docs pages"
    for target in targets:
        assert not target.startswith(("http:", "https:", "/", "..")), target
        assert (ROOT / target.split("#")[0]).exists(), f"README links a missing file: {target}"
    assert "../shared" not in text


def test_planned_features_say_so_and_name_their_issue():
    """What is not built says so and names its issue; what is built is not called planned."""
    motion = (ROOT / "docs" / "motion.md").read_text()
    # the larynx slide from plain video is the default, with its figures beside the held
    # value's and what holds it back
    assert "**The larynx's slide tau per frame** (`track/larynx.py`, `--tau photometric`, " \
        "the\n   default" in motion
    assert "larynx slide held at the keyframe fit's (`--tau fixed`)" in motion
    assert "**what holds the larynx slide back now.**" in motion.lower()
    for page in ("register.md", "motion.md"):
        assert "not available yet" not in (ROOT / "docs" / page).read_text().lower(), page
    from hack_render.cli import load_commands

    names = set(load_commands())
    assert {"register", "transfer", "track"} <= names
    readme = (ROOT / "README.md").read_text()
    planned = readme.split("Not available yet")[-1] if "Not available yet" in readme else ""
    for cmd in ("register", "transfer", "track"):
        assert f"`{cmd}`" not in planned
        assert f"| `{cmd}` |" in readme, f"{cmd}: missing from the README's command table"


def test_every_benchmark_result_has_provenance():
    files = sorted((ROOT / "bench" / "results").glob("*.json"))
    assert len(files) >= 20
    assert not list((ROOT / "docs").glob("bench_*.json")), "results belong in bench/results"
    for path in files:
        data = json.loads(path.read_text())
        for key in ("commit", "date", "machine", "command"):
            assert isinstance(data.get(key), str) and data[key].strip(), (path.name, key)
        assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?|unknown", data["commit"]), path.name
        assert re.match(r"\d{4}-\d\d-\d\dT", data["date"]), path.name
        assert "previous" not in path.stem, f"{path.name}: name a result by what it ran"


def test_write_result_records_commit_date_machine_and_command(tmp_path):
    prov = _bench_module("provenance")
    out = prov.write_result(tmp_path / "r.json", {"median": 1.5, "commit": "stale"},
                            argv=["bench/bench_x.py", "--subjects", "2"])
    data = json.loads(out.read_text())
    assert list(data)[:4] == ["commit", "date", "machine", "command"]
    git = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                         text=True, check=False)
    head = git.stdout.strip() if git.returncode == 0 else "unknown"  # outside a git checkout
    assert data["commit"].split("-")[0] == head
    assert data["command"] == "python bench/bench_x.py --subjects 2"
    assert data["median"] == 1.5 and not (tmp_path / "r.json.tmp").exists()


def test_recorded_keeps_what_a_benchmark_prints(tmp_path, capsys):
    prov = _bench_module("provenance")
    with prov.recorded(tmp_path / "p.json", "Toy", argv=["bench/bench_toy.py"]):
        print("ratio 1.25x")
    assert capsys.readouterr().out == "ratio 1.25x\n"  # still printed
    data = json.loads((tmp_path / "p.json").read_text())
    assert data["printed"] == ["ratio 1.25x"] and data["title"] == "Toy"
    assert data["command"] == "python bench/bench_toy.py" and data["commit"]
    with pytest.raises(ZeroDivisionError), prov.recorded(tmp_path / "q.json", "Toy"):
        print(1 / 0)
    assert not (tmp_path / "q.json").exists()  # a failed run writes no result


def test_benchmarks_page_is_generated_from_the_results():
    page = _bench_module("make_benchmarks_page")
    text = page.render(page.load())
    assert (ROOT / "docs" / "benchmarks.md").read_text() == text, \
        "docs/benchmarks.md is stale: run python bench/make_benchmarks_page.py"
    for path in (ROOT / "bench" / "results").glob("*.json"):
        assert f"bench/results/{path.name}" in text, f"{path.name} is not on the page"


def _need_mkdocs():
    missing = [m for m in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers")
               if importlib.util.find_spec(m) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed: bash scripts/setup.sh --test "
                    "installs the docs tools")


def _mkdocs_build(config: Path, site: Path):
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f",
                           str(config), "--site-dir", str(site)], cwd=config.parent,
                          capture_output=True, text=True, check=False, timeout=300,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})


def test_mkdocs_build_strict(tmp_path):
    _need_mkdocs()
    res = _mkdocs_build(ROOT / "mkdocs.yml", tmp_path / "site")
    assert res.returncode == 0, res.stderr[-3000:]
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert "personalize" in api and "distribute_head_rotation" in api  # docstrings rendered


@pytest.mark.parametrize("breakage, message", [
    ("see [this page](missing.md)", "missing.md"),
    ("::: hack_render.geometry.no_such_function", "no_such_function"),
])
def test_strict_build_fails_on_a_broken_link_or_api_reference(tmp_path, breakage, message):
    """The CI check has teeth: the same site with one broken link, or one reference to a
    name that has no docstring to render, does not build."""
    _need_mkdocs()
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    with open(tmp_path / "docs" / "troubleshooting.md", "a") as f:
        f.write(f"\n{breakage}\n")
    (tmp_path / "mkdocs.yml").write_text(f"INHERIT: {ROOT / 'mkdocs.yml'}\n"
                                         "docs_dir: docs\nhooks: []\n")
    res = _mkdocs_build(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert res.returncode != 0 and message in res.stderr + res.stdout, res.stderr[-2000:]
