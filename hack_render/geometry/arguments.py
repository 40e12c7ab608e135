"""The geometry model's call arguments: what :meth:`HackModel.forward` (and
:class:`~hack_render.geometry.personalized.PersonalizedHack`, :func:`reference_forward`)
do with their inputs before any geometry: shapes checked, NaN and inf refused, expression
strings turned into weights, missing inputs filled and every input broadcast to the batch."""

from __future__ import annotations

import torch

from hack_render.errors import HackError
from hack_render.geometry import larynx as _larynx


def psi_value(model, value):
    """psi given as an expression string or dict (one row), or a list of them (and/or
    weight vectors), one per batch row -> (E,) or (B, E); anything else unchanged."""
    if isinstance(value, (str, dict)):
        return model.expression_vector(value)
    if isinstance(value, (list, tuple)) and any(isinstance(v, (str, dict)) for v in value):
        dd = {"dtype": model.template.dtype, "device": model.template.device}
        return torch.stack([model.expression_vector(v) if isinstance(v, (str, dict))
                            else torch.as_tensor(v, **dd) for v in value])
    return value


def forward_arguments(model, beta, psi, theta, global_orient, transl, eta, tau
                      ) -> dict[str, torch.Tensor]:
    """The forward's inputs (:meth:`HackModel.forward`'s arguments) as tensors on the
    model's dtype and device: each checked for its shape (HackError naming it), NaN and
    inf refused, psi's strings and dicts turned into weights (:func:`psi_value`), the
    missing ones filled (zeros, eta = 1: ``larynx.ETA_DEFAULT``) and every one broadcast
    to the batch size."""
    dtype, device = model.template.dtype, model.template.device
    given = {"beta": beta, "psi": psi, "theta": theta, "global_orient": global_orient,
             "transl": transl, "eta": eta, "tau": tau}
    trailing = {"beta": None, "psi": (model.num_expressions,), "theta": (model.num_joints, 3),
                "global_orient": (3,), "transl": (3,), "eta": (), "tau": ()}
    batch = 1
    out: dict[str, torch.Tensor] = {}
    for name, value in given.items():
        if value is None:
            continue
        if name == "psi":
            value = psi_value(model, value)
        value = torch.as_tensor(value, dtype=dtype, device=device)
        if not torch.is_floating_point(value):
            value = value.to(dtype)
        want = trailing[name]
        if name == "beta":
            if value.ndim == 1:
                value = value[None]
            if value.ndim != 2 or value.shape[1] > model.num_shape:
                raise HackError(f"beta: expected shape (B, <= {model.num_shape}), found "
                                f"{tuple(value.shape)}.")
        else:
            if value.ndim == len(want):
                value = value[None]
            if value.ndim != len(want) + 1 or tuple(value.shape[1:]) != want:
                raise HackError(f"{name}: expected shape (B, {', '.join(map(str, want))})"
                                f"{' i.e. (B,)' if not want else ''}, found {tuple(value.shape)}.")
        if value.shape[0] != 1:
            if batch != 1 and value.shape[0] != batch:
                raise HackError(f"{name}: batch size {value.shape[0]} does not match "
                                f"batch size {batch} of the other parameters.")
            batch = value.shape[0]
        out[name] = value
    check_finite(out)
    zeros = {"beta": (0,), "psi": (model.num_expressions,), "theta": (model.num_joints, 3),
             "global_orient": (3,), "transl": (3,), "eta": (), "tau": ()}
    for name, shp in zeros.items():
        if name not in out:
            fill = _larynx.ETA_DEFAULT if name == "eta" else 0.0
            out[name] = torch.full((batch,) + shp, fill, dtype=dtype, device=device)
        elif out[name].shape[0] != batch:
            out[name] = out[name].expand((batch,) + tuple(out[name].shape[1:]))
    return out


def check_finite(given: dict[str, torch.Tensor]) -> None:
    """Raise naming the first input with a NaN or inf. One check over all inputs at once
    (a handful of small ops per input otherwise, a tenth of a B = 1 forward's overhead)."""
    if not given:
        return
    flat = torch.cat([v.detach().reshape(-1) for v in given.values()])
    if bool(torch.isfinite(flat).all()):
        return
    for name, value in given.items():
        if not torch.isfinite(value.detach()).all():
            raise HackError(f"{name}: contains NaN or inf values; pass finite numbers.")


def shares_identity(beta: torch.Tensor) -> bool:
    """Whether a (B, s) beta is one identity for the whole batch, so that per-identity work
    may be done once: one row, a row expanded over the batch (stride 0: the gradient of the
    one row is what autograd wants), or equal rows that need no gradient."""
    if beta.shape[0] == 1 or beta.shape[1] == 0 or beta.stride(0) == 0:
        return True
    if torch.is_grad_enabled() and beta.requires_grad:
        return False
    return bool((beta == beta[:1]).all())
