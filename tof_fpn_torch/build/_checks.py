"""Argument checks of the builders: each raises :class:`ValueError` naming the parameter, what was
given and what is allowed, before any design or estimate runs."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from torch import nn

from ..cameras import PROFILES, profile
from ..design import MAX_ORDER
from ..runtime._checks import normalize_dims
from ..runtime.fir import BORDER_MODES

__all__ = [
    "check_border",
    "check_camera",
    "check_dim",
    "check_filter_options",
    "check_flag",
    "check_fusion_options",
    "check_keys",
    "check_module",
    "check_order",
    "check_real",
    "check_rho",
]


def check_flag(name: str, value: object) -> bool:
    """``value`` as a bool; ValueError unless it is True or False."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _is_real(value: object) -> bool:
    return not isinstance(value, (bool, np.bool_)) and isinstance(
        value, (int, float, np.integer, np.floating)
    )


def check_real(
    name: str,
    value: object,
    *,
    minimum: float = -math.inf,
    maximum: float = math.inf,
    open_minimum: bool = False,
    optional: bool = False,
) -> float | None:
    """``value`` as a float in ``[minimum, maximum]`` (``(minimum, maximum]`` with
    ``open_minimum``), finite; None passes where ``optional``."""
    if value is None and optional:
        return None
    ok = _is_real(value) and math.isfinite(float(value))  # type: ignore[arg-type]
    if ok:
        v = float(value)  # type: ignore[arg-type]
        ok = (minimum < v if open_minimum else minimum <= v) and v <= maximum
    if not ok:
        allowed = "a finite real number"
        if minimum > -math.inf or maximum < math.inf:
            allowed += f" in {'(' if open_minimum else '['}{minimum:g}, {maximum:g}]"
        raise ValueError(f"{name} must be {allowed}{' or None' if optional else ''}, got {value!r}")
    return v


def check_order(order: object) -> int:
    """``order`` as an int in ``[1, MAX_ORDER]`` (the design refuses orders below its fixed zeros'
    degree, which depends on the notches)."""
    if (
        isinstance(order, (bool, np.bool_))
        or not isinstance(order, (int, np.integer))
        or not 1 <= int(order) <= MAX_ORDER
    ):
        raise ValueError(f"order must be an integer in [1, {MAX_ORDER}], got {order!r}")
    return int(order)


def check_rho(rho: object, *, optional: bool = False) -> float | None:
    """``rho`` as a float > 0 (the design checks the upper limit its notches allow)."""
    return check_real("rho", rho, minimum=0.0, open_minimum=True, optional=optional)


def check_dim(dim: object, *, optional: bool = False) -> None:
    """ValueError unless ``dim`` is -1, -2 or (-2, -1) (or None where ``optional``)."""
    if dim is None and optional:
        return
    try:
        normalize_dims(dim)
    except ValueError as exc:
        raise ValueError(f"{exc}{' (or None)' if optional else ''}") from None


def check_border(border: object) -> None:
    """ValueError unless ``border`` is one of the FIR's border modes."""
    if not isinstance(border, str) or border not in BORDER_MODES:
        raise ValueError(f"border must be one of {BORDER_MODES}, got {border!r}")


def check_camera(name: str, camera: object) -> None:
    """ValueError unless ``camera`` is None or the name of a camera profile."""
    if camera is None:
        return
    if not isinstance(camera, str):
        raise ValueError(
            f"{name} must be a camera profile {sorted(PROFILES)} or None, got {camera!r}"
        )
    profile(camera)


def check_module(name: str, value: object) -> None:
    """ValueError unless ``value`` is None or an ``nn.Module``."""
    if value is not None and not isinstance(value, nn.Module):
        raise ValueError(f"{name} must be an nn.Module or None, got {type(value).__name__}")


def check_keys(name: str, value: object, allowed: tuple[str, ...]) -> dict:
    """``value`` (None or a mapping with keys from ``allowed``) as a dict."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} must be a dict or None, got {type(value).__name__}")
    unknown = sorted(str(k) for k in value if k not in allowed)
    if unknown:
        raise ValueError(f"{name} has unknown keys {unknown}; allowed: {list(allowed)}")
    return dict(value)


def check_filter_options(
    border: object,
    trainable: object,
    allow_shift: object,
    compensate_delay: object,
    unit_dc: object,
    max_ripple_db: object,
) -> None:
    """The checks of :func:`~tof_fpn_torch.build.filter_from_design`'s options besides the
    design's own (``order``, ``rho``, ``notches`` and ``band_weights``: checked by
    :func:`~tof_fpn_torch.design.design_fpn`; ``dim`` by :func:`check_dim`)."""
    check_border(border)
    for name, flag in (
        ("trainable", trainable),
        ("allow_shift", allow_shift),
        ("compensate_delay", compensate_delay),
        ("unit_dc", unit_dc),
    ):
        check_flag(name, flag)
    check_real("max_ripple_db", max_ripple_db, optional=True)


def check_fusion_options(camera: object, low: object, high: object, floor: object) -> None:
    """The checks of the eq. (11) fusion's options (``low < high`` is the fusion's own check)."""
    check_camera("camera", camera)
    check_real("low", low, minimum=0.0, optional=True)
    check_real("high", high, minimum=0.0, optional=True)
    check_real("floor", floor, minimum=0.0, maximum=1.0)
