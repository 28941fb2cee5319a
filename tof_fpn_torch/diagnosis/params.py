"""Fitted parameters: physical values and the unconstrained variables the optimiser moves.

Every parameter has a key (``"photons.responsivity"``, ``"cyclic_error.cos1"``), a kind and a
scale: ``lin`` (value = u * scale, any sign), ``log`` (value = scale * e^u, > 0), ``logit``
(value = scale / (1 + e^-u), in (0, scale)), ``relgain`` (value = e^(u scale) - 1, > -1, about
``u * scale`` near zero: a relative change of a level, which cannot take the level to zero or
below), ``abs`` (value = scale |u|, >= 0, linear near zero) or ``rootabs`` (value =
sqrt(scale |u|), >= 0: a standard deviation whose variance is linear in ``u``, so that the
optimiser does not stall on the plateau a logarithm or a softplus has near zero). The model
stores physical values; the fit works on ``u`` so that one step of the optimiser is about one
scale. A parameter that is a charge (e-) is marked ``charge``: while the conversion
gain is fitted it moves with it, so that its value in DN stays put (decorrelated variables,
:func:`~tof_fpn_torch.diagnosis.fit.fit`).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import torch

__all__ = ["RELGAIN_FLOOR", "SCALE_CYCLIC", "SCALE_DEPTH", "ParamSpec", "from_u", "to_u"]

#: Scale of the depth-like parameters (m): the optimiser moves them in mm steps ...
SCALE_DEPTH: float = 1e-3
#: ... and the correlation harmonics (and other small relative sizes) in 1 % steps.
SCALE_CYCLIC: float = 0.01
#: Lowest value of a ``relgain`` parameter: a level may fall to a millionth, never to zero.
RELGAIN_FLOOR: float = -1.0 + 1e-6
_TINY: float = sys.float_info.min


@dataclass(frozen=True)
class ParamSpec:
    """One fitted scalar: ``key`` (``"owner.field"``), ``kind`` (``lin``, ``log``, ``logit``,
    ``relgain``, ``abs``, ``rootabs``), ``scale``, ``unit`` (for readers) and ``charge`` (a
    charge in e-: it moves with the conversion gain while that is fitted)."""

    key: str
    kind: str = "lin"
    scale: float = 1.0
    unit: str = ""
    charge: bool = False


def to_u(spec: ParamSpec, value: float) -> float:
    """The optimiser's variable for a physical ``value``."""
    v = float(value)
    if spec.kind == "lin":
        return v / spec.scale
    if spec.kind == "log":
        return math.log(max(v, 1e-300) / spec.scale)
    if spec.kind == "logit":
        p = min(max(v / spec.scale, 1e-12), 1 - 1e-12)
        return math.log(p / (1 - p))
    if spec.kind == "rootabs":
        return v * v / spec.scale
    if spec.kind == "relgain":
        return math.log1p(max(v, RELGAIN_FLOOR)) / spec.scale
    if spec.kind == "abs":
        return v / spec.scale
    raise ValueError(f"unknown parameter kind {spec.kind!r}")


def from_u(spec: ParamSpec, u):
    """The physical value of ``u`` (a float or a tensor; keeps the autograd graph)."""
    if spec.kind == "lin":
        return u * spec.scale
    if spec.kind == "log":  # floored: far out, e^u underflows to zero
        if isinstance(u, torch.Tensor):
            return (spec.scale * torch.exp(u)).clamp_min(_TINY)
        return max(spec.scale * math.exp(u), _TINY)
    if spec.kind == "logit":
        return spec.scale * (
            torch.sigmoid(u) if isinstance(u, torch.Tensor) else 1 / (1 + math.exp(-u))
        )
    if spec.kind == "abs":
        return spec.scale * (u.abs() if isinstance(u, torch.Tensor) else abs(u))
    if spec.kind == "relgain":  # floored: far out, e^x - 1 rounds to -1 itself
        if isinstance(u, torch.Tensor):
            return torch.expm1(u * spec.scale).clamp_min(RELGAIN_FLOOR)
        return max(math.expm1(u * spec.scale), RELGAIN_FLOOR)
    if spec.kind == "rootabs":
        if isinstance(u, torch.Tensor):
            return torch.sqrt(spec.scale * u.abs() + 1e-300)
        return math.sqrt(spec.scale * abs(u))
    raise ValueError(f"unknown parameter kind {spec.kind!r}")
