"""Labelled datasets: sampling, rendering, labels, sharding, resumption, executors.

Public API:
    load_config, check_config, DEFAULTS (config.py); sample_spec, model_kwargs (sampling.py);
    LABELS, to_labels, soft_masks, larynx_peak (labels.py); SampleRenderer (worker.py);
    Job, run, parse_shard, write_manifest, read_record (runner.py); contact_sheet (preview.py).
CLI: ``hack-render dataset`` and ``hack-render dataset preview`` (cli.py); docs/datasets.md.
"""

from hack_render.dataset.config import DEFAULTS, check_config, load_config
from hack_render.dataset.labels import LABELS
from hack_render.dataset.runner import Job, parse_shard, read_record, run, write_manifest
from hack_render.dataset.sampling import model_kwargs, sample_spec

__all__ = ["DEFAULTS", "LABELS", "Job", "check_config", "load_config", "model_kwargs",
           "parse_shard", "read_record", "run", "sample_spec", "write_manifest"]
