"""`--hair` and `--hair-color` of `hack-render render`, `turntable` and `export`: the style
to grow (:mod:`hack_render.hair`), checked before anything heavy, and its groom.

``--hair`` takes an archetype name (:data:`hack_render.hair.style.ARCHETYPES`), ``none`` (no
groom at all: the scene of earlier versions, ICT's lash cards) or a .json / .yaml file
holding a hair mapping (the fields of :class:`~hack_render.hair.style.HairStyle`, at the
top level or under a ``hair`` key, as in a parameter file). Without it the parameter
file's ``hair`` section (``--params``) is used, and without that the command's default.
``bald`` is a bald scalp that still has brows and lashes (strands); ``none`` has no hair.
``--hair-color`` sets the melanin of whatever style that gives.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from hack_render.errors import HackError
from hack_render.geometry.params import MAX_PARAMS_BYTES, parse_params_text
from hack_render.hair.groom import grow_cached
from hack_render.hair.regions import HeadSurface
from hack_render.hair.style import ARCHETYPES, HairStyle

HAIR_HELP = ("Hair, brows, lashes and beard as strands (docs/hair.md): a style name "
             "(bald, shaved, crew, short, bob, long, ponytail, bun, afro; 'bald' keeps "
             "brows and lashes), 'none' (no strands: ICT's lash cards, as before), or a "
             ".json/.yaml file holding a hair mapping, e.g. {\"archetype\": \"long\", "
             "\"beard\": \"stubble\", \"lod\": 0.5}. Default: the --params file's 'hair' "
             "section, else {default}. A full head of short hair costs about 1.9x the render "
             "time, long hair 5x (docs/hair.md).")
HAIR_COLOR_HELP = ("Hair colour as melanin: a name (black, dark-brown, brown, light-brown, "
                   "blonde, platinum, red, auburn, white) or 'EUMELANIN,PHEOMELANIN' (0..20 "
                   "each; eumelanin ~0.3 blonde, 1.3 brown, 8 black; pheomelanin reddens).")

#: What ``--hair none`` (and a null ``hair`` section) means: no groom.
NONE = ("none", "off", "no")


def hair_option(default: str) -> Any:
    return typer.Option(None, "--hair", help=HAIR_HELP.replace("{default}", default),
                        show_default=False)


HairColorOpt = typer.Option(None, "--hair-color", help=HAIR_COLOR_HELP, show_default=False)


def _hair_file(path: Path) -> Any:
    if path.is_dir() or not path.is_file():
        found = "expected a file, found a folder" if path.is_dir() else "file not found"
        raise HackError(f"--hair {path}: {found}; pass a style name (bald, shaved, crew, "
                        f"short, bob, long, ponytail, bun, afro), 'none' or an existing "
                        f".json/.yaml file.")
    if path.stat().st_size > MAX_PARAMS_BYTES:
        raise HackError(f"--hair {path}: expected a small .json/.yaml hair mapping, found "
                        f"{path.stat().st_size / 1e6:.0f} MB.")
    try:
        text = path.read_text(encoding="utf-8")
    except (UnicodeDecodeError, OSError) as exc:
        raise HackError(f"--hair {path}: not readable as UTF-8 text ({exc}).") from exc
    try:
        data = parse_params_text(text, path.suffix, str(path))
    except HackError as exc:
        raise HackError(str(exc).replace("--params", "--hair", 1)) from exc
    if isinstance(data, dict) and "hair" in data:  # a hair section, or a parameter file
        data = data["hair"]
    return data


def hair_style(hair: str | None, hair_color: str | None, params_hair: Any = None,
               default: str = "none"):
    """The :class:`~hack_render.hair.style.HairStyle` of the options, or None (no groom).

    ``hair``: the ``--hair`` text (None: not given); ``params_hair``: the parameter file's
    ``hair`` section (absent: None, so a null section cannot be told from none: both are
    no groom); ``default``: ``--hair``'s value when neither is given. HackError (exit 2)
    naming the option for a bad value."""
    source = "--hair"
    if hair is None:
        data: Any = params_hair if params_hair is not None else default
        source = "--params hair" if params_hair is not None else "--hair"
    else:
        text = hair.strip()
        if text.lower() in NONE or text.lower() in ARCHETYPES:
            data = text.lower()
        elif Path(text).suffix.lower() in (".json", ".yaml", ".yml"):
            data = _hair_file(Path(text).expanduser())
            source = f"--hair {text}"
        else:
            raise HackError(f"--hair: expected a style name ({', '.join(ARCHETYPES)}), 'none' "
                            f"or a .json/.yaml file holding a hair mapping, found {hair!r}.")
    if data is None or (isinstance(data, str) and data.lower() in NONE):
        if hair_color is not None:
            raise HackError(f"--hair-color: no hair to colour ({source} is none); "
                            "pass --hair STYLE too, e.g. --hair short --hair-color "
                            f"{hair_color}.")
        return None
    try:
        style = HairStyle.from_dict(data)
    except HackError as exc:
        raise HackError(f"{source}: {exc}") from exc
    if hair_color is not None:
        try:
            style = style.with_colour(hair_color)
        except HackError as exc:
            raise HackError(f"--hair-color: {exc}") from exc
    return style


def groom_of(style, model):
    """The groom of ``style`` on ``model`` (a model file's arrays, a ``PosingModel`` or a
    ``HackModel``), or None for no style; remembered for the process
    (:func:`hack_render.hair.groom.grow_cached`)."""
    if style is None:
        return None
    return grow_cached(HeadSurface.from_model(model), style)
