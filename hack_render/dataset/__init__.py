"""Labelled datasets: sampling, rendering, labels, sharding, resumption, executors.

Public API:
    load_config, check_config, DEFAULTS (config.py); sample_spec, model_kwargs (sampling.py);
    LABELS, to_labels, soft_masks, larynx_peak (labels.py); SampleRenderer (worker.py);
    Job, run, parse_shard, write_manifest, read_record (runner.py); contact_sheet (preview.py).
CLI: ``hack-render dataset`` and ``hack-render dataset preview`` (cli.py); docs/datasets.md.
"""

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported lazily (below)
    from hack_render.dataset.config import DEFAULTS, check_config, load_config
    from hack_render.dataset.labels import LABELS
    from hack_render.dataset.runner import Job, parse_shard, read_record, run, write_manifest
    from hack_render.dataset.sampling import model_kwargs, sample_spec

#: the public names, imported on first use: `hack-render dataset --help` imports this
#: package, and its modules load Mitsuba (tests/test_structure.py LAZY_PACKAGES)
_LAZY = {"DEFAULTS": "config", "check_config": "config", "load_config": "config",
         "LABELS": "labels", "Job": "runner", "parse_shard": "runner", "read_record": "runner",
         "run": "runner", "write_manifest": "runner", "model_kwargs": "sampling",
         "sample_spec": "sampling"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f"hack_render.dataset.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'hack_render.dataset' has no attribute {name!r}")


__all__ = sorted(_LAZY)
