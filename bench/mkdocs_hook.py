"""mkdocs hook: regenerate docs/benchmarks.md from bench/results/*.json before each build,
so the benchmarks page can never drift from the result files."""

from __future__ import annotations

import importlib.util
from pathlib import Path


def on_pre_build(config, **kwargs) -> None:  # noqa: ARG001 - mkdocs hook signature
    path = Path(__file__).with_name("make_benchmarks_page.py")
    spec = importlib.util.spec_from_file_location("make_benchmarks_page", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.write()
