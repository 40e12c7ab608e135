"""Expressions by name: FACS action units and the model's shape names -> psi, without torch.

Shared by :meth:`hack_render.geometry.model.HackModel.expression_vector` and posing
without torch (:mod:`hack_render.geometry.posing`); the text form is checked on input by
:func:`hack_render.geometry.params.parse_expression`.
"""

from __future__ import annotations

import re

import numpy as np

from hack_render.errors import HackError

#: FACS action units that no shape of the ARKit set (ICT-FaceKit's expressions) makes, and
#: why: the expression parser names them instead of calling them unknown. The AU table
#: itself is built by :func:`hack_render.learn.ict_default.facs_au_table`.
FACS_WITHOUT_SHAPES: dict[str, str] = {
    "AU11": "nasolabial deepener: no ARKit shape deepens the nasolabial furrow alone",
    "AU13": "sharp lip puller: no ARKit shape; AU12 (mouthSmile) is the nearest",
    "AU23": "lip tightener: no ARKit shape narrows the lips' red margins",
    "AU25": "lips part: no shape parts the lips without the jaw (mouthClose is its opposite)",
    "AU27": "mouth stretch: no ARKit shape stretches the mouth open beyond a jaw drop; AU26 "
            "(jawOpen, jaw drop) is the nearest",
}


def expression_weights(spec: str | dict[str, float], expression_names, au_names,
                       au_matrix: np.ndarray) -> np.ndarray:
    """psi (E,) of a model (its ``expression_names``, ``au_names`` and ``au_matrix`` (A, E))
    from shape names and FACS action units, in ``au_matrix``'s dtype.

    ``spec`` is a dict or a string like ``"AU12=0.7, jawOpen=0.4"``; AU entries add their
    shapes' rows, shape names add themselves. Unknown names are a :class:`HackError` that
    says what is known (:meth:`~hack_render.geometry.model.HackModel.expression_vector`
    and posing without torch, :mod:`hack_render.geometry.posing`, both use it).
    """
    expression_names, au_names = list(expression_names), list(au_names)
    if isinstance(spec, str):
        items = {}
        for part in filter(None, (p.strip() for p in re.split(r"[,;]", spec))):
            if "=" not in part:
                raise HackError(f"expression '{part}': expected NAME=VALUE, e.g. AU12=0.7 or jawOpen=0.4.")
            k, v = part.split("=", 1)
            try:
                items[k.strip()] = float(v)
            except ValueError as exc:
                raise HackError(f"expression '{part}': value {v!r} is not a number.") from exc
        spec = items
    if not isinstance(spec, dict):
        raise HackError(f"expression: expected a string like 'AU12=0.7, jawOpen=0.4' or a "
                        f"mapping of names to weights, found {type(spec).__name__}.")
    psi = np.zeros(len(expression_names), dtype=au_matrix.dtype)
    for name, value in spec.items():
        value = float(value)
        if not np.isfinite(value):
            raise HackError(f"expression '{name}': value {value} is not finite.")
        if name in au_names:
            psi = psi + value * au_matrix[au_names.index(name)]
        elif name in expression_names:
            psi[expression_names.index(name)] += value
        elif name.upper() in FACS_WITHOUT_SHAPES and name.upper() not in au_names:
            raise HackError(f"expression '{name}': FACS {name.upper()} "
                            f"({FACS_WITHOUT_SHAPES[name.upper()]}). Known AUs: "
                            f"{', '.join(au_names)}.")
        else:
            close = [n for n in au_names + expression_names if n.lower() == name.lower()]
            hint = f" Did you mean {close[0]!r}?" if close else ""
            raise HackError(f"expression '{name}': unknown action unit or shape name.{hint} "
                            f"Known AUs: {', '.join(au_names)}; shape names: "
                            f"`hack-render model info` lists them.")
    return psi
