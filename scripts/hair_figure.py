"""Hair archetypes side by side for docs/images/hair_archetypes.png (issue 61).

Each panel is what ``hack-render render --hair STYLE --hair-color COLOUR`` renders (full
grooms, lod 1): the README's skin (``--alpha 0.8,-0.6,0.4``), studio light, an orbit camera
at the panel's yaw (5 degrees up, 85 mm), 49 spp, SSS, denoised, ACES tone map.

    python scripts/hair_figure.py [--res 256] [--spp 49] [--out docs/images/...]
        [--panels short:full:dark-brown:30,long:none:auburn:-30,afro:none:black:20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from hack_render.geometry.model_file import default_model_path
from hack_render.geometry.posing import PosingModel
from hack_render.hair.groom import grow
from hack_render.hair.regions import HeadSurface
from hack_render.hair.style import HairStyle
from hack_render.io.image import to_srgb8
from hack_render.render.parts import Topology
from hack_render.render.scene import HeadScene, RenderSettings
from hack_render.render.skin_maps import skin_maps
from scenes import cameras, lights

PANELS = "short:full:dark-brown:30,long:none:auburn:-30,afro:none:black:20"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=49)
    ap.add_argument("--panels", default=PANELS, help="archetype:beard:colour:yaw, ...")
    ap.add_argument("--out", default="docs/images/hair_archetypes.png")
    args = ap.parse_args()
    import imageio.v3 as iio

    posing = PosingModel.from_file(default_model_path())
    v = posing.vertices().astype(np.float64)
    topo, surf = Topology.from_model(posing), HeadSurface.from_model(posing)
    maps = skin_maps([0.8, -0.6, 0.4], None, None)
    settings = RenderSettings(args.res, args.res, args.spp, pixel_filter="box")
    tiles = []
    for panel in args.panels.split(","):
        arch, beard, colour, yaw = panel.split(":")
        t0 = time.perf_counter()
        groom = grow(surf, HairStyle.archetype_style(arch, beard=beard).with_colour(colour))
        cam = cameras.orbit(args.res, args.res, 85.0, float(yaw), 5.0)
        head = HeadScene(topo, v, lights.preset("studio"), cam, settings, maps, hair=groom)
        img = head.composite(head.denoise(head.render(backdrop=False, sss=True)))
        tiles.append(to_srgb8(img[..., :3], 0.0, "aces"))
        print(f"{panel}: {groom.num_strands} strands, {time.perf_counter() - t0:.0f} s")
    iio.imwrite(args.out, np.concatenate(tiles, axis=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
