"""Preview sheets of texture sets (sRGB-encoded PNG, written atomically)."""

from __future__ import annotations

import numpy as np

from appearance.colour_space import srgb_encode
from hack_render.io import atomic_path


def preview_sheet(maps: dict[str, np.ndarray], path, title: str = "") -> None:
    """A 2 x 2 sheet: diffuse (sRGB), specular, roughness, normal ((n + 1) / 2)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(12, 6.5))
    ax[0, 0].imshow(srgb_encode(maps["diffuse"]))
    ax[0, 0].set_title("diffuse (sRGB)")
    im = ax[0, 1].imshow(maps["specular"][..., 0], vmin=0, vmax=1, cmap="magma")
    ax[0, 1].set_title("specular intensity (x F0 0.028)")
    fig.colorbar(im, ax=ax[0, 1], fraction=0.025)
    im = ax[1, 0].imshow(maps["roughness"][..., 0], vmin=0.2, vmax=0.9, cmap="viridis")
    ax[1, 0].set_title("perceptual roughness")
    fig.colorbar(im, ax=ax[1, 0], fraction=0.025)
    ax[1, 1].imshow(np.clip(maps["normal"] * 0.5 + 0.5, 0, 1))
    ax[1, 1].set_title("normal (tangent space, OpenGL)")
    for a in ax.ravel():
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
