"""A coloured scan's colours baked into the model's UV layout.

For every texel of the skin atlas (``appearance.uv.rasterize_layout``: H x 2H, the
model's UVs) the point it shows on the registered mesh is found (its triangle and
barycentric coordinates), and the scan's colour is read at the nearest scan surface
point (:class:`~hack_render.register.scan.SurfaceIndex`), if that point is within
``max_distance`` and faces the same way. Texels so seen are the validity mask. The rest
are filled from the left-right mirror texel where that was seen, then from the
appearance model A(alpha) with alpha fitted (least squares) to the seen texels' diffuse.
Specular, roughness and normal maps come from A(alpha): a scan's colours do not
separate them. The scan's colours carry its capture lighting; they are used as diffuse
albedo as they are (say so when that matters).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from appearance import AppearanceModel
from appearance.texture_io import write_map, write_png
from appearance.uv import rasterize_layout
from hack_render.register.pipeline import Registration
from hack_render.register.scan import Scan, SurfaceIndex, vertex_normals

MAX_DISTANCE_M = 0.003


def texel_points(vertices: np.ndarray, faces: np.ndarray, layout) -> tuple[np.ndarray, np.ndarray]:
    """(points (T, 3), normals (T, 3)) of the layout's valid texels on a mesh in the
    template's topology (``vertices`` (N, 3), ``faces`` the template's triangles)."""
    valid = layout.mask.ravel()
    face = layout.face.ravel()[valid]
    bary = layout.bary.reshape(-1, 3)[valid].astype(np.float64)
    tri = faces[face]
    p = np.einsum("tk,tkc->tc", bary, vertices[tri])
    vn = vertex_normals(vertices, faces)
    n = np.einsum("tk,tkc->tc", bary, vn[tri])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return p, n


def _mirror_index(layout) -> np.ndarray:
    """For each valid texel, the valid texel nearest to its mirror image (x -> -x) on the
    template (indices into the valid texels)."""
    from scipy.spatial import cKDTree

    pos = layout.position.reshape(-1, 3)[layout.mask.ravel()].astype(np.float64)
    mirrored = pos * np.array([-1.0, 1.0, 1.0])
    return cKDTree(pos).query(mirrored, workers=-1)[1]


def _fit_alpha(diffuse: np.ndarray, seen: np.ndarray, height: int, app) -> np.ndarray:
    """Least-squares alpha (k,) of the appearance model's diffuse to the seen texels."""
    import torch.nn.functional as F

    a_h = app.height
    img = torch.as_tensor(diffuse.transpose(2, 0, 1)[None], dtype=torch.float32)
    w = torch.as_tensor(seen[None, None].astype(np.float32))
    f = height // a_h
    pooled = F.avg_pool2d(img * w, f) / F.avg_pool2d(w, f).clamp_min(1e-6)
    wp = F.avg_pool2d(w, f)[0, 0].numpy().ravel()
    target = pooled[0].permute(1, 2, 0).reshape(-1, 3).numpy()
    valid = np.flatnonzero(app.mask_np.ravel())
    use = wp[valid] > 0.5
    if use.sum() < 100:
        return np.zeros(app.n_components)
    # the model's compact texels are its valid texels in order
    basis = app.basis.numpy().reshape(app.n_components, -1, 7)[:, use, :3]
    mean = app.mean.numpy().reshape(-1, 7)[use, :3]
    A = basis.reshape(app.n_components, -1).T.astype(np.float64)
    b = (target[valid[use]] - mean).ravel().astype(np.float64)
    lam = 1e-3 * len(b)  # ridge towards the mean: alpha ~ N(0, I)
    return np.linalg.solve(A.T @ A + lam * np.eye(A.shape[1]), A.T @ b)


def _upsample(img: np.ndarray, height: int) -> np.ndarray:
    import torch.nn.functional as F

    t = torch.as_tensor(np.ascontiguousarray(img.transpose(2, 0, 1))[None], dtype=torch.float32)
    return F.interpolate(t, size=(height, 2 * height), mode="bilinear",
                         align_corners=False)[0].permute(1, 2, 0).numpy()


def bake(vertices_m: np.ndarray, faces: np.ndarray, scan: Scan, height: int = 1024
         ) -> dict[str, np.ndarray]:
    """Bake the scan's colours. ``vertices_m``: the registration in the scan's frame, metres.

    Returns {"diffuse" (H, 2H, 3) linear, "seen" (H, 2H) bool, "confidence" (H, 2H) in
    [0, 1] (1 seen, 0.5 mirrored, 0 from A(alpha)), "specular", "roughness", "normal",
    "alpha"}."""
    layout = rasterize_layout(height)
    p, n = texel_points(vertices_m, faces, layout)
    index = SurfaceIndex(scan, spacing=0.0005)
    d, i = index.nearest(p, MAX_DISTANCE_M)
    ok = np.isfinite(d)
    ii = np.where(ok, i, 0)
    ok &= (n * index.normals[ii]).sum(1) > 0.3
    cols = np.where(ok[:, None], index.colors[ii], 0.0)
    mirror = _mirror_index(layout)
    from_mirror = ~ok & ok[mirror]
    cols[from_mirror] = cols[mirror[from_mirror]]
    h, w = layout.mask.shape
    valid = layout.mask.ravel()
    diffuse = np.zeros((h * w, 3))
    diffuse[valid] = cols
    seen = np.zeros(h * w, bool)
    seen[valid] = ok
    conf = np.zeros(h * w)
    conf[valid] = np.where(ok, 1.0, np.where(from_mirror, 0.5, 0.0))
    app = AppearanceModel.load()
    got = np.zeros(h * w, bool)
    got[valid] = ok | from_mirror
    alpha = _fit_alpha(diffuse.reshape(h, w, 3), got.reshape(h, w), height, app)
    maps = app.maps(torch.as_tensor(alpha[None], dtype=torch.float32))
    up = {k: _upsample(getattr(maps, k)[0].numpy(), height)
          for k in ("diffuse", "specular", "roughness", "normal")}
    model_diffuse = up["diffuse"].reshape(-1, 3)
    diffuse[~got] = model_diffuse[~got]
    # texels outside the atlas' skin take the nearest skin texel (as A(alpha) does)
    diffuse = diffuse[layout.fill]
    nrm = up["normal"]
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-12)
    return {"diffuse": np.clip(diffuse.reshape(h, w, 3), 0, 1).astype(np.float32),
            "seen": seen.reshape(h, w), "confidence": conf.reshape(h, w).astype(np.float32),
            "specular": up["specular"].astype(np.float32),
            "roughness": up["roughness"].astype(np.float32), "normal": nrm.astype(np.float32),
            "alpha": alpha}


def bake_scan_colors(reg: Registration, model, scan: Scan, folder: Path, height: int
                     ) -> tuple[dict[str, Path], dict]:
    """Bake and write ``folder``/{diffuse,specular,roughness,normal}.exr, mask.png and
    confidence.png; returns ({name: path}, report)."""
    maps = bake(reg.vertices * scan.scale, model.faces.numpy(), scan, height)
    folder.mkdir(parents=True, exist_ok=True)
    files = {}
    for name in ("diffuse", "specular", "roughness", "normal"):
        files[name] = folder / f"{name}.exr"
        write_map(files[name], name, maps[name])
    files["mask"] = folder / "mask.png"
    write_png(files["mask"], maps["seen"].astype(np.float32), bits=8, srgb=False)
    files["confidence"] = folder / "confidence.png"
    write_png(files["confidence"], maps["confidence"], bits=8, srgb=False)

    skin = int(rasterize_layout(height).mask.sum())
    report = {"height": height, "seen_fraction_of_skin": float(maps["seen"].sum() / skin),
              "mirrored_fraction_of_skin": float((maps["confidence"] == 0.5).sum() / skin),
              "alpha": np.asarray(maps["alpha"]).tolist(),
              "note": "diffuse: the scan's colours where seen (capture lighting included), "
                      "mirrored where only the other side was seen, A(alpha) elsewhere; "
                      "specular, roughness, normal: A(alpha)"}
    return files, report
