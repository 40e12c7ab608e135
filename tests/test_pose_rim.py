"""The mesh's open cuts (`geometry.normals.open_boundary`) and the pose learner's
``hold_rim`` (issue 60): correctives held at zero on the cut, which a corrective would lift
(the mesh's inside then shows; docs/model.md, "The chain gate")."""

from __future__ import annotations

import numpy as np
import torch

from hack_render.geometry.model_file import default_model_path, load_model_file
from hack_render.geometry.normals import open_boundary


def test_open_boundary_of_small_meshes_and_the_default_model():
    square = np.array([[0, 1, 2], [0, 2, 3]])
    assert open_boundary(square, 5).tolist() == [True, True, True, True, False]
    tetra = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    assert not open_boundary(tetra, 4).any()
    arrays, _ = load_model_file(default_model_path())
    rim = open_boundary(arrays["faces"], len(arrays["template_vertices"]))
    t = np.asarray(arrays["template_vertices"])
    # the bust's cut is open: the lowest vertices lie on it
    assert rim[np.argsort(t[:, 1])[:10]].all() and rim[np.argmin(t[:, 1])]


def test_held_rows_stay_zero_in_the_learner_and_its_file():
    """With ``hold_rim`` the learner's correctives are exactly zero on the cut's vertices
    (for any identity, before and after a step) and the result it writes is zero there
    too, while the other rows move."""
    from hack_render.learn.full_model import energy_learner

    arrays, _ = load_model_file(default_model_path())
    learner = energy_learner(arrays, num_components=int(np.shape(arrays["pose_pca_components"])[0]),
                             expressions=False, hold_rim=True)
    learner.start_from(arrays)
    held = (learner.keep[:, 0] == 0).numpy()
    assert 10 < held.sum() < 0.2 * len(held)
    beta = torch.randn(3, 20, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    b = learner.blendshapes(beta).detach()
    assert (b[:, :, held] == 0).all() and b[:, :, ~held].abs().max() > 1e-4
    res = learner.fit(iterations=1, identities=1, poses=2, hard=0, progress=False, seed=4)
    assert (res.pose_basis[:, held] == 0).all() and (res.components[:, :, held] == 0).all()
    assert np.abs(res.pose_basis[:, ~held]).max() > 1e-4
