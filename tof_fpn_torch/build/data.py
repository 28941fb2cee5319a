"""The FPN stage from data: the pieces calibration frames call for, measured with
:mod:`tof_fpn_torch.analysis` (periodic stripes -> notches, their strength against the amplitude
-> the eq. (11) fusion and the gate's stripe scale, broadband column / row offsets -> a
destriper): :func:`suppression_from_data`. The pieces' own builders are in :mod:`.fusion` and
:mod:`.broadband`."""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from typing import Final, Literal

import torch
from torch import nn

from .. import constants as K
from ..analysis.stripes import StripeEstimate, estimate_stripes
from ..design import max_rho
from ..runtime import FPNSuppression
from ._checks import (
    check_dim,
    check_filter_options,
    check_flag,
    check_fusion_options,
    check_keys,
    check_order,
    check_rho,
)
from .broadband import broadband_from_data
from .design import (
    DEFAULT_ALLOW_SHIFT,
    DEFAULT_BORDER,
    DEFAULT_COMPENSATE_DELAY,
    DEFAULT_GATE,
    DEFAULT_TRAINABLE,
    DEFAULT_UNIT_DC,
    MAX_RIPPLE_DB,
    suppression_from_design,
)
from .fusion import measure_fusion

__all__ = [
    "AUTO",
    "ESTIMATE_OPTIONS",
    "NOTCH_MERGE",
    "RHO_SHARE",
    "suppression_from_data",
]


#: :func:`suppression_from_data`: detected frequencies closer than this (radians per sample)
#: become one notch ...
NOTCH_MERGE = 0.02
#: ... and without a given ``rho`` the design takes ``min(DEFAULT_RHO, RHO_SHARE * max_rho)`` of
#: the notches (a margin below the largest transition width they allow)
RHO_SHARE = 0.9
#: ``destripe`` of :func:`suppression_from_data` that measures the broadband offsets on the frames
AUTO: Final = "auto"
#: The options of :func:`~tof_fpn_torch.analysis.estimate_stripes` that ``estimate_kwargs`` of
#: :func:`suppression_from_data` may set (the frames and ``false_alarm`` are its own parameters)
ESTIMATE_OPTIONS: tuple[str, ...] = tuple(
    name
    for name, p in inspect.signature(estimate_stripes).parameters.items()
    if p.kind is p.KEYWORD_ONLY and name != "false_alarm"
)


def suppression_from_data(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None = None,
    order: int = K.DEFAULT_ORDER,
    rho: float | None = None,
    *,
    false_alarm: float = K.DETECTION_FALSE_ALARM,
    estimate_kwargs: dict | None = None,
    camera_hint: str | None = None,
    dim: int | tuple[int, ...] | None = None,
    adaptive: bool | None = None,
    camera: str | None = None,
    low: float | None = None,
    high: float | None = None,
    floor: float = K.FUSION_FLOOR,
    gate: bool = DEFAULT_GATE,
    destripe: nn.Module | Literal["auto"] | None = AUTO,
    border: str = DEFAULT_BORDER,
    trainable: bool = DEFAULT_TRAINABLE,
    allow_shift: bool = DEFAULT_ALLOW_SHIFT,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = DEFAULT_COMPENSATE_DELAY,
    unit_dc: bool = DEFAULT_UNIT_DC,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
) -> FPNSuppression:
    """A stage with the pieces the data call for (never one the data do not).

    The periodic components :func:`~tof_fpn_torch.analysis.estimate_stripes` reports become the
    notches (closer than :data:`NOTCH_MERGE`: one), their orientations ``dim``. With amplitudes the
    fusion is fitted to the stripes' strength against the amplitude (:func:`fusion_from_data`),
    the gate's stripe power calibrated on the same frames (``stripe_scale``). Broadband offsets in
    what the notches leave get a :class:`~tof_fpn_torch.runtime.Destripe`
    (:func:`broadband_from_data`). Without stripes the stage has no notch. The estimate is kept in
    ``module.estimate``; the stage is built by :func:`suppression_from_design`.

    (Longer than 80 lines only by its 22 documented options; its 40 lines of logic are calls of
    the helpers and of :func:`suppression_from_design`, and cannot be split further.)

    Args:
        frames, amplitudes: (B, 1, H, W) calibration depth frames of one camera (any unit, one
            fixed pattern) and their amplitudes, or None (no fusion measured).
        order: the notch filter's order (default Table I's 20).
        rho: the transition half-width (fraction of ``pi``); default ``min(DEFAULT_RHO,
            RHO_SHARE max_rho)`` of the notches found (:data:`RHO_SHARE` 0.9).
        false_alarm: largest false-alarm probability of a reported stripe (default 0.01).
        estimate_kwargs: more options of :func:`~tof_fpn_torch.analysis.estimate_stripes` (keys
            from :data:`ESTIMATE_OPTIONS`), or None.
        camera_hint: the camera profile whose thresholds the fusion takes where the frames are
            too small to measure the stripes on (else the noise rule, :func:`fusion_from_noise`).
        dim: the notch filter's orientation; default (None) that of the stripes found.
        adaptive: the eq. (11) fusion; default (None) when ``amplitudes`` are given.
        camera, low, high: a camera profile's or given thresholds instead of measured ones (a
            ``high`` alone replaces the measured ``high``).
        floor: the fusion's floor where it is not fitted (default 0.2).
        gate: the per-frame stripe gate (default True).
        destripe: ``"auto"`` (default: :func:`broadband_from_data`), None, or a module to run
            first.
        border, trainable, allow_shift, band_weights, compensate_delay, unit_dc, max_ripple_db:
            as in :func:`filter_from_design`.

    Raises:
        ValueError: an option is invalid (the message names it, its value and what is allowed),
            or the frames (:func:`~tof_fpn_torch.analysis.estimate_stripes`) or the design are.
    """
    order, rho = check_order(order), check_rho(rho, optional=True)
    estimate_options = check_keys("estimate_kwargs", estimate_kwargs, ESTIMATE_OPTIONS)
    auto_destripe, given = _check_data_options(camera_hint, dim, adaptive, gate, destripe)
    check_filter_options(border, trainable, allow_shift, compensate_delay, unit_dc, max_ripple_db)
    check_fusion_options(camera, low, high, floor)
    est = estimate_stripes(frames, amplitudes, false_alarm=false_alarm, **estimate_options)
    if not est.components:
        return _without_notch(frames, amplitudes, est, auto=auto_destripe, destripe=given)
    notches, found_dim, rho = _notches(est, rho)
    adaptive = amplitudes is not None if adaptive is None else adaptive
    measure = amplitudes is not None and adaptive and low is None and camera is None
    module = suppression_from_design(
        order,
        rho,
        notches=notches,
        dim=found_dim if dim is None else dim,
        adaptive=adaptive and not measure,  # the measured fusion is attached below
        camera=camera,
        low=low,
        high=high,
        floor=floor,
        gate=gate,
        destripe=given,
        border=border,
        trainable=trainable,
        allow_shift=allow_shift,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
    )
    if measure and amplitudes is not None:
        measure_fusion(module, frames, amplitudes, high=high, floor=floor, camera_hint=camera_hint)
    if auto_destripe:  # what the notch stage leaves: broadband offsets, if any
        with torch.no_grad():
            notched = module(frames, amplitudes)
        module.destripe = broadband_from_data(notched, amplitudes)
    module.estimate = est
    return module


def _check_data_options(
    camera_hint: object, dim: object, adaptive: object, gate: object, destripe: object
) -> tuple[bool, nn.Module | None]:
    """The checks of :func:`suppression_from_data`'s own options; whether ``destripe`` is
    :data:`AUTO`, and the module given (or None)."""
    if camera_hint is not None and not isinstance(camera_hint, str):
        raise ValueError(
            f"camera_hint must be a camera profile's name or None, got {camera_hint!r}"
        )
    check_dim(dim, optional=True)
    if adaptive is not None:
        check_flag("adaptive", adaptive)
    check_flag("gate", gate)
    if isinstance(destripe, nn.Module) or destripe is None:
        return False, destripe
    if not (isinstance(destripe, str) and destripe == AUTO):
        raise ValueError(f"destripe must be {AUTO!r}, None or an nn.Module, got {destripe!r}")
    return True, None


def _without_notch(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None,
    est: StripeEstimate,
    *,
    auto: bool,
    destripe: nn.Module | None,
) -> FPNSuppression:
    """The stage of frames without periodic stripes: no notch; the destriper
    :func:`broadband_from_data` finds (``auto``), else ``destripe``."""
    found = broadband_from_data(frames, amplitudes) if auto else destripe
    module = FPNSuppression(None, None, destripe=found)
    module.estimate = est
    return module


def _notches(
    est: StripeEstimate, rho: float | None
) -> tuple[tuple[float, ...], int | tuple[int, ...], float]:
    """The notches of the components found (closer than :data:`NOTCH_MERGE`: one), their
    orientations, and ``rho`` (given, or :data:`RHO_SHARE` of the largest the notches allow, at
    most the default)."""
    merged: list[float] = []
    for f in sorted({c.frequency for c in est.components}):  # one notch for close peaks
        if merged and f - merged[-1] < NOTCH_MERGE:
            continue
        merged.append(f)
    dims = sorted({c.dim for c in est.components})
    if rho is None:
        rho = min(K.DEFAULT_RHO, RHO_SHARE * max_rho(merged))
    return tuple(merged), tuple(dims) if len(dims) > 1 else dims[0], rho
