"""A registration's files, each written whole (temporary name, then renamed), the report
last, so a folder with ``report.json`` is complete and one without it is not.

- ``registered.obj``: the registered mesh in the model's vertex order (UVs, materials),
  in the scan's frame and units, so it lies on the scan in any viewer.
- ``registered_model.obj``: the model's own fit, before the free-form offsets.
- ``params.json``: beta, psi, theta, global_orient, transl, eta, tau in the model's frame
  (metres), for ``render --params``, ``turntable --params`` and ``export --params``.
- ``offsets.npy``: (N, 3) free-form offsets, metres, model frame (zero off the skin).
- ``error.ply``: the registered mesh coloured by each vertex's distance to the scan
  (blue 0 mm, red >= 3 mm, grey where not measured: off the skin, and where the scan has
  no surface for the vertex, e.g. the back of the head of a face scan:
  :func:`hack_render.register.pipeline.measure`), the distance also as a ``quality``
  property (millimetres; -1 not measured).
- ``error.png``: that heat map ray cast from the front and both sides, with a labelled
  colour bar (matplotlib) and the scan's errors in the title.
- ``landmarks.json``: the 3-D landmarks used (scan frame and units) and where they came from.
- ``textures/``: baked skin maps when the scan has colours (see :mod:`.bake`).
- ``report.json``: errors, per-stage times, status (``ok`` or ``failed`` with reasons).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hack_render.geometry.obj_io import write_mesh
from hack_render.geometry.params import save_params
from hack_render.io import atomic_path, write_json
from hack_render.io.image import to_srgb8
from hack_render.register.pipeline import Registration
from hack_render.register.scan import srgb_to_linear
from hack_render.render.mesh_views import MeshViews
from scenes.cameras import Camera, framing_distance, intrinsics, look_at

HEAT_MAX_MM = 3.0


def heat_colors(err_mm: np.ndarray, vmax: float = HEAT_MAX_MM) -> np.ndarray:
    """(N, 3) sRGB colours in [0, 1] of errors (nan: grey), matplotlib's ``turbo``."""
    from matplotlib import colormaps

    x = np.clip(np.nan_to_num(err_mm, nan=0.0) / vmax, 0, 1)
    c = colormaps["turbo"](x)[:, :3]
    c[~np.isfinite(err_mm)] = 0.5
    return c


def write_error_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, err_mm: np.ndarray
                    ) -> Path:
    """Binary PLY: positions, uchar RGB from :func:`heat_colors`, float ``quality`` (mm)."""
    rgb = np.round(heat_colors(err_mm) * 255).astype(np.uint8)
    vdt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                    ("blue", "u1"), ("quality", "<f4")])
    va = np.empty(len(vertices), vdt)
    for k, n in enumerate("xyz"):
        va[n] = vertices[:, k]
    va["red"], va["green"], va["blue"] = rgb.T
    va["quality"] = np.nan_to_num(err_mm, nan=-1.0)
    fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    fa = np.empty(len(faces), fdt)
    fa["n"], fa["i"] = 3, faces
    header = ("ply\nformat binary_little_endian 1.0\ncomment hack-render register: distance "
              "to the scan, mm (quality; -1 = not measured)\n"
              f"element vertex {len(vertices)}\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
              f"property float quality\nelement face {len(faces)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    with atomic_path(path) as tmp:
        tmp.write_bytes(header.encode() + va.tobytes() + fa.tobytes())
    return path


def heat_map_views(model_vertices: np.ndarray, faces: np.ndarray, err_mm: np.ndarray,
                   size: int = 384) -> list[np.ndarray]:
    """Front, left and right views (each (size, size, 3) uint8) of the error colours."""
    v = np.asarray(model_vertices, np.float64)
    centre = 0.5 * (v.min(0) + v.max(0))
    views = MeshViews(v, faces, srgb_to_linear(heat_colors(err_mm)), size, size)
    K = intrinsics(size, size, 50.0)
    d = framing_distance(K, size, size, float(np.ptp(v, 0).max()))
    tiles = []
    for yaw in (0.0, 60.0, -60.0):
        a = np.radians(yaw)
        eye = centre + d * np.array([np.sin(a), 0.0, np.cos(a)])
        R, t = look_at(eye, centre)
        img = views.render(Camera(K, R, t, size, size, "heat"))
        tiles.append(to_srgb8(img[..., :3], operator="clip"))
    return tiles


def write_heat_map(path: Path, model_vertices: np.ndarray, faces: np.ndarray,
                   err_mm: np.ndarray, title: str) -> Path:
    """``path`` (PNG): the three views side by side with a labelled colour bar (mm)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    tiles = heat_map_views(model_vertices, faces, err_mm)
    fig, axes = plt.subplots(1, 3, figsize=(10.5, 3.9))
    for ax, img, name in zip(axes, tiles, ("front", "left", "right"), strict=True):
        ax.imshow(img)
        ax.set_title(name, fontsize=9)
        ax.axis("off")
    sm = plt.cm.ScalarMappable(norm=Normalize(0, HEAT_MAX_MM), cmap=colormaps["turbo"])
    bar = fig.colorbar(sm, ax=axes, fraction=0.025, pad=0.01)
    bar.set_label(f"distance to the scan, mm (grey: not measured, no scan there; >= "
                  f"{HEAT_MAX_MM:g} red)", fontsize=8)
    fig.suptitle(title, fontsize=10)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png", facecolor="white")
    plt.close(fig)
    return path


def write_registration(reg: Registration, model, outdir: Path, landmarks: dict,
                       extra_files: dict | None = None) -> list[Path]:
    """Write every file of one registration into ``outdir``; ``report.json`` last."""
    outdir.mkdir(parents=True, exist_ok=True)
    faces = model.faces.numpy()
    uvs, uv_faces = model.uvs.numpy(), model.uv_faces.numpy()
    written = [write_mesh(outdir / "registered.obj", reg.vertices, faces, uvs, uv_faces),
               write_mesh(outdir / "registered_model.obj", reg.model_vertices, faces, uvs,
                          uv_faces),
               save_params(outdir / "params.json", reg.params)]
    with atomic_path(outdir / "offsets.npy") as tmp, open(tmp, "wb") as fh:
        np.save(fh, reg.offsets.astype(np.float32), allow_pickle=False)
    written.append(outdir / "offsets.npy")
    written.append(write_error_ply(outdir / "error.ply", reg.vertices, faces, reg.vertex_error))
    # the heat map on the mesh in the model's frame (upright, facing the camera)
    err = reg.report["scan_to_mesh_mm"]["all"]
    title = (f"{reg.report['scan']}: scan-to-mesh mean {err.get('mean', float('nan')):.2f} mm, "
             f"p95 {err.get('p95', float('nan')):.2f} mm ({reg.report['status']})")
    written.append(write_heat_map(outdir / "error.png", _model_frame(reg), faces,
                                  reg.vertex_error, title))
    written.append(write_json(outdir / "landmarks.json", landmarks, indent=1))
    written += list((extra_files or {}).values())
    report = dict(reg.report)
    report["files"] = sorted(str(p.relative_to(outdir)) for p in written)
    written.append(write_json(outdir / "report.json", report, indent=1))
    return written


def _model_frame(reg: Registration) -> np.ndarray:
    """The registered vertices moved back into the model's frame (metres, upright)."""
    sim = reg.report["similarity_scan_to_model"]
    scale_m = reg.report.get("scan_scale_m", 1.0)
    s, R, t = sim["scale"], np.asarray(sim["R"]), np.asarray(sim["t"])
    return s * (reg.vertices * scale_m) @ R.T + t
