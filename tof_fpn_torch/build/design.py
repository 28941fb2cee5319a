"""Builders from the offline design: notch taps designed with NumPy, then the run-time
modules (:class:`~tof_fpn_torch.runtime.FPNFilter`, :class:`~tof_fpn_torch.runtime.FPNSuppression`)
with the design recorded on them."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from .. import constants as K
from ..cameras import profile
from ..design import FPNDesign, compensate_half_sample, design_fpn, fixed_zero_taps
from ..runtime import AmplitudeFusion, FPNFilter, FPNSuppression, TrainableFusion, keep_zeros
from ._checks import (
    check_dim,
    check_filter_options,
    check_flag,
    check_fusion_options,
    check_module,
)

__all__ = [
    "DEFAULT_ADAPTIVE",
    "DEFAULT_ALLOW_SHIFT",
    "DEFAULT_BORDER",
    "DEFAULT_COMPENSATE_DELAY",
    "DEFAULT_DIM",
    "DEFAULT_GATE",
    "DEFAULT_TRAINABLE",
    "DEFAULT_UNIT_DC",
    "DesignRefused",
    "HALF_SAMPLE_MAX_EDGE",
    "MAX_RIPPLE_DB",
    "filter_from_design",
    "suppression_from_design",
    "trainable_suppression",
]


#: The builders refuse designs whose passband ripple is worse than this (dB): such a "notch filter"
#: changes the scene more than it removes stripes (e.g. 0 dB ripple with H(0) = 2 doubles depth).
MAX_RIPPLE_DB = -20.0
#: The half-sample interpolator of odd orders is designed up to the top passband edge, at most this
#: fraction of pi.
HALF_SAMPLE_MAX_EDGE = 0.95

# The builders' shared defaults (every builder that takes the option defaults to these):
#: the orientation the notch filter runs along: -1 (width: column stripes), -2 (height: row
#: stripes) or (-2, -1) (both)
DEFAULT_DIM: int | tuple[int, ...] = -1
#: the FIR's border handling (one of ``tof_fpn_torch.runtime.fir.BORDER_MODES``)
DEFAULT_BORDER = "reflect"
#: the filter's taps are fixed (True: trainable parameters)
DEFAULT_TRAINABLE = False
#: an odd order's half-sample shift is refused unless compensated (True: accepted)
DEFAULT_ALLOW_SHIFT = False
#: odd orders are convolved with a half-sample interpolator, so the output stays on the input grid
DEFAULT_COMPENSATE_DELAY = True
#: the design has ``H(0) = 1`` exactly (False: the paper's unconstrained minimax design)
DEFAULT_UNIT_DC = True
#: the stage blends filtered and input depth by amplitude (eq. 11)
DEFAULT_ADAPTIVE = True
#: the stage's per-frame stripe gate is on (stripe-free frames pass unchanged)
DEFAULT_GATE = True


class DesignRefused(ValueError):
    """A design whose passband ripple is worse than the builder's ``max_ripple_db``: the filter
    would change the scene more than it removes stripes (a caller that chose the notches itself
    can fall back without a notch)."""


def _design(
    order: int,
    rho: float,
    notches: Sequence[float],
    band_weights: Sequence[float] | None,
    compensate_delay: bool,
    unit_dc: bool,
    max_ripple_db: float | None,
) -> tuple[FPNDesign, torch.Tensor, bool]:
    """The design, its taps (delay-compensated for odd orders when asked) and whether they were
    compensated; ValueError if the ripple is worse than ``max_ripple_db``."""
    design = design_fpn(order, rho, notches=notches, band_weights=band_weights, unit_dc=unit_dc)
    if max_ripple_db is not None and not design.ripple_db <= max_ripple_db:
        raise DesignRefused(
            f"the design {{order {order}, rho {rho:g}}} for notches "
            f"{[round(w, 4) for w in design.notches]} has a passband ripple of "
            f"{design.ripple_db:.1f} dB (its passband gain strays from 1 by up to "
            f"{10 ** (design.ripple_db / 20):.2f}; DC gain {design.dc_gain:.3f}); the stage "
            f"needs <= {max_ripple_db:g} dB (up to {10 ** (max_ripple_db / 20):.2f}): use a "
            "higher order or a larger rho (max_ripple_db=None accepts it anyway)"
        )
    taps = design.taps
    compensated = bool(compensate_delay) and taps.size % 2 == 0
    if compensated:
        # the interpolator's band reaches the top passband edge (at most HALF_SAMPLE_MAX_EDGE pi)
        taps = compensate_half_sample(
            taps, band_edge=float(min(design.bands[-1, 1], HALF_SAMPLE_MAX_EDGE * math.pi))
        )
    return design, torch.from_numpy(taps), compensated


def filter_from_design(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    dim: int | tuple[int, ...] = DEFAULT_DIM,
    border: str = DEFAULT_BORDER,
    trainable: bool = DEFAULT_TRAINABLE,
    allow_shift: bool = DEFAULT_ALLOW_SHIFT,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = DEFAULT_COMPENSATE_DELAY,
    unit_dc: bool = DEFAULT_UNIT_DC,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
) -> FPNFilter:
    """Design taps with :func:`tof_fpn_torch.design.design_fpn` and build an :class:`FPNFilter`
    (its taps are the design's, delay-compensated for odd orders: a module, not another way to
    get taps; ``design_fpn(...).taps`` are the taps). The design is kept in ``module.design``.

    Args:
        order: filter order ``N`` (``N + 1`` taps); default Table I's 20.
        rho: transition half-width as a fraction of ``pi`` (eq. 8); default Table I's 0.14.
        notches: the stripe frequencies in ``(0, pi]``, radians per sample; default ``(2pi/3,
            pi)``.
        dim: the orientation the filter runs along: -1 (width: column stripes, default), -2
            (height: row stripes) or (-2, -1) (both).
        border: the FIR's border handling, one of ``"reflect"`` (default), ``"replicate"``,
            ``"circular"``, ``"zeros"``.
        trainable: make the taps trainable parameters (default False).
        allow_shift: accept the half-sample shift of an odd order without compensation (the
            paper's odd filters; default False).
        band_weights: optional relative weight per passband (see :func:`design_fpn`).
        compensate_delay: convolve the taps of an odd order with a half-sample interpolator
            (:func:`tof_fpn_torch.design.compensate_half_sample`), so the output stays on the
            input grid (default); with False an odd order needs ``allow_shift=True``.
        unit_dc: constrain ``H(0) = 1`` (default; False: the paper's design).
        max_ripple_db: refuse a design whose passband ripple is worse than this (dB; default
            :data:`MAX_RIPPLE_DB`); None accepts any.

    Raises:
        ValueError: an option is invalid (the message names it, its value and what is allowed),
            or the design's ripple is worse than ``max_ripple_db``.
    """
    check_dim(dim)
    check_filter_options(border, trainable, allow_shift, compensate_delay, unit_dc, max_ripple_db)
    design, taps, compensated = _design(
        order,
        rho,
        notches=notches,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
    )
    module = FPNFilter(
        taps,
        dim=dim,
        border=border,
        trainable=trainable,
        allow_shift=allow_shift,
        order=design.order,
        rho=design.rho,
        notches=design.notches,
        compensated=compensated,
    )
    module.design = design
    return module


def suppression_from_design(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    dim: int | tuple[int, ...] = DEFAULT_DIM,
    adaptive: bool = DEFAULT_ADAPTIVE,
    camera: str | None = None,
    low: float | None = None,
    high: float | None = None,
    floor: float = K.FUSION_FLOOR,
    gate: bool = DEFAULT_GATE,
    destripe: nn.Module | None = None,
    border: str = DEFAULT_BORDER,
    trainable: bool = DEFAULT_TRAINABLE,
    allow_shift: bool = DEFAULT_ALLOW_SHIFT,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = DEFAULT_COMPENSATE_DELAY,
    unit_dc: bool = DEFAULT_UNIT_DC,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
) -> FPNSuppression:
    """Design taps and build an :class:`FPNSuppression`: notch filter, eq. (11) fusion (when
    ``adaptive``), the stripe gate (when ``gate``), and an optional ``destripe`` module first.

    The fusion thresholds are in the camera's amplitude units: ``low`` / ``high`` when given, else
    those of the ``camera`` profile (:mod:`tof_fpn_torch.cameras`), else CamCube's (the paper's 70
    and 350). For a camera without a profile, measure them with :func:`fusion_from_data`.

    Defaults: Table I's best adaptive filter ``{20, 0.14}`` with notches at ``2pi/3`` and ``pi``,
    unit DC gain, gated. The paper's stage is ``suppression_from_design(unit_dc=False,
    gate=False)``.

    Args:
        order, rho, notches, dim: the notch filter's design and orientation, as in
            :func:`filter_from_design`.
        adaptive: blend filtered and input depth by amplitude (eq. 11; default True).
        camera: the camera profile whose fusion thresholds to use (default CamCube's).
        low, high: the fusion's amplitude thresholds (``delta_A = 1`` below ``low``, ``floor``
            from ``high`` on), overriding the profile's.
        floor: the fusion's weight of the filtered depth for strong signals (default 0.2).
        gate: the per-frame stripe gate (default True: frames without stripes pass unchanged).
        destripe: a module run before the notch filter (e.g. a
            :class:`~tof_fpn_torch.runtime.Destripe`), or None (default).
        border, trainable, allow_shift, band_weights, compensate_delay, unit_dc, max_ripple_db:
            as in :func:`filter_from_design`.

    Raises:
        ValueError: an option is invalid (the message names it, its value and what is allowed),
            the camera profile has no thresholds, or the design's ripple is worse than
            ``max_ripple_db``.
    """
    check_fusion_options(camera, low, high, floor)  # the filter's: in filter_from_design
    adaptive = check_flag("adaptive", adaptive)
    check_flag("gate", gate)
    check_module("destripe", destripe)
    thresholds = _thresholds(camera, low, high) if adaptive else None
    filt = filter_from_design(
        order,
        rho,
        notches=notches,
        dim=dim,
        border=border,
        trainable=trainable,
        allow_shift=allow_shift,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
    )
    fusion = None if thresholds is None else AmplitudeFusion(*thresholds, floor)
    return FPNSuppression(filt, fusion, destripe=destripe, gate=gate)


def _thresholds(camera: str | None, low: float | None, high: float | None) -> tuple[float, float]:
    prof = profile(camera if camera is not None else "camcube")
    lo = prof.fusion_low if low is None else low
    hi = prof.fusion_high if high is None else high
    if lo is None or hi is None:
        raise ValueError(
            f"camera profile {prof.name!r} has no fusion thresholds ({prof.source}); pass low= "
            "and high=, or measure them with tof_fpn_torch.build.fusion_from_data"
        )
    return float(lo), float(hi)


def trainable_suppression(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    dim: int | tuple[int, ...] = DEFAULT_DIM,
    camera: str | None = None,
    low: float | None = None,
    high: float | None = None,
    floor: float = K.FUSION_FLOOR,
    gate: bool = DEFAULT_GATE,
    border: str = DEFAULT_BORDER,
    allow_shift: bool = DEFAULT_ALLOW_SHIFT,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = DEFAULT_COMPENSATE_DELAY,
    unit_dc: bool = DEFAULT_UNIT_DC,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
) -> FPNSuppression:
    """The stage as a trainable first layer, initialised from the design.

    The notch taps train through ``G`` of ``H = A G`` with the zeros of ``A`` held
    (:func:`~tof_fpn_torch.runtime.keep_zeros`); the fusion is a
    :class:`~tof_fpn_torch.runtime.TrainableFusion` starting at the camera's thresholds (CamCube's
    by default, or ``low`` / ``high``). Freeze with :func:`tof_fpn_torch.runtime.freeze` before
    export.

    Args:
        order, rho, notches, dim: the notch filter's design and orientation, as in
            :func:`filter_from_design`.
        camera, low, high, floor, gate: the fusion's starting thresholds and the stripe gate, as
            in :func:`suppression_from_design`.
        border, allow_shift, band_weights, compensate_delay, unit_dc, max_ripple_db: as in
            :func:`filter_from_design`.

    Raises:
        ValueError: an option is invalid (the message names it, its value and what is allowed),
            the camera profile has no thresholds, or the design's ripple is worse than
            ``max_ripple_db``.
    """
    check_fusion_options(camera, low, high, floor)  # the filter's: in filter_from_design
    check_flag("gate", gate)
    lo, hi = _thresholds(camera, low, high)
    filt = filter_from_design(
        order,
        rho,
        notches=notches,
        dim=dim,
        border=border,
        trainable=True,
        allow_shift=allow_shift,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
    )
    keep_zeros(filt, fixed_zero_taps(notches))
    return FPNSuppression(filt, TrainableFusion(lo, hi, floor), gate=gate)
