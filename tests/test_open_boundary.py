"""`geometry.normals.open_boundary`: a mesh's open cuts, the one helper of the fit's contour
and scan registration."""

from __future__ import annotations

import numpy as np

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
    # the bust's cut is open: the ten lowest vertices lie on it
    assert rim[np.argsort(t[:, 1])[:10]].all()
