"""bench/bench_pose_arap.py's pairs: with ``--pose-bench`` the whole pose bench's own pairs
(those of ``bench/results/pose_space.json``), so that ARAP's figures on a family of it are
comparable with the bench's; ``--families`` and ``--every`` keep a part of them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
import bench_pose_arap

from hack_render.geometry.deformation import sample_pose_space


def _args(**kw) -> argparse.Namespace:
    base = {"model": None, "poses": 200, "identities": 3, "seed": 2100, "pose_bench": False,
            "families": "", "every": 1}
    return argparse.Namespace(**{**base, **kw})


def test_pose_bench_pairs_are_the_pose_space_benchs():
    names, theta, fam_of, betas = bench_pose_arap.pairs(_args(pose_bench=True))
    fams = sample_pose_space(2000, 21)  # bench_pose_space.py's defaults
    assert names == list(fams)
    assert torch.equal(theta, torch.cat(list(fams.values())))
    assert torch.equal(betas, torch.randn(10, 20, generator=torch.Generator().manual_seed(21)))
    assert np.bincount(fam_of).tolist() == [len(v) for v in fams.values()]


def test_families_and_every_keep_that_family_thinned():
    names, theta, fam_of, _ = bench_pose_arap.pairs(_args(pose_bench=True, families="head_x"))
    head_x = sample_pose_space(2000, 21)["head_x"]
    assert names == ["head_x"] and torch.equal(theta, head_x) and (fam_of == 0).all()
    _, thin, fam_thin, _ = bench_pose_arap.pairs(_args(pose_bench=True, families="head_z,head_x",
                                                       every=10))
    both = torch.cat([head_x, sample_pose_space(2000, 21)["head_z"]])  # the bench's order
    assert torch.equal(thin, both[::10])
    # indices into the names as given: head_z is 0, head_x 1
    assert fam_thin.tolist() == ([1] * len(head_x) + [0] * (len(both) - len(head_x)))[::10]
    with pytest.raises(ValueError, match="unknown"):
        bench_pose_arap.pairs(_args(families="head_w"))
