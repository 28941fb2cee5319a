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
from ..design import compensate_half_sample, design_fpn, fixed_zero_taps
from ..runtime import AmplitudeFusion, FPNFilter, FPNSuppression, TrainableFusion, keep_zeros

__all__ = [
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


def _design(order, rho, notches, band_weights, compensate_delay, unit_dc, max_ripple_db):
    design = design_fpn(order, rho, notches=notches, band_weights=band_weights, unit_dc=unit_dc)
    if max_ripple_db is not None and not design.ripple_db <= max_ripple_db:
        raise ValueError(
            f"the design {{order {order}, rho {rho:g}}} for notches "
            f"{[round(w, 4) for w in design.notches]} has a passband ripple of "
            f"{design.ripple_db:.1f} dB (DC gain {design.dc_gain:.3f}); the stage needs "
            f"<= {max_ripple_db:g} dB: use a higher order or a larger rho (max_ripple_db=None "
            "accepts it anyway)"
        )
    taps = design.taps
    compensated = bool(compensate_delay) and taps.size % 2 == 0
    if compensated:
        # the interpolator's band reaches the top passband edge (at most HALF_SAMPLE_MAX_EDGE pi)
        taps = compensate_half_sample(
            taps, band_edge=float(min(design.bands[-1, 1], HALF_SAMPLE_MAX_EDGE * math.pi))
        )
    meta = {
        "order": design.order,
        "rho": design.rho,
        "notches": design.notches,
        "compensated": compensated,
    }
    return design, torch.from_numpy(taps), meta


def filter_from_design(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = True,
    unit_dc: bool = True,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
    **kwargs,
) -> FPNFilter:
    """Design taps with :func:`tof_fpn_torch.design.design_fpn` and build an :class:`FPNFilter`
    (its taps are the design's, delay-compensated for odd orders: a module, not another way to
    get taps; ``design_fpn(...).taps`` are the taps).

    ``compensate_delay`` (default) convolves the taps of an odd order with a half-sample
    interpolator (:func:`tof_fpn_torch.design.compensate_half_sample`), so the output stays on the
    input grid; with False an odd order needs ``allow_shift=True`` (the paper's filters).
    ``unit_dc`` constrains ``H(0) = 1`` (default; the paper's design with False). A design whose
    ripple is worse than ``max_ripple_db`` is refused with a ``ValueError``. ``kwargs`` go to
    :class:`FPNFilter` (``dim``, ``border``, ``trainable``, ``allow_shift``). The design is kept
    in ``module.design``.
    """
    design, taps, meta = _design(
        order, rho, notches, band_weights, compensate_delay, unit_dc, max_ripple_db
    )
    module = FPNFilter(taps, **kwargs, **meta)
    module.design = design
    return module


def suppression_from_design(
    order: int = K.DEFAULT_ORDER,
    rho: float = K.DEFAULT_RHO,
    *,
    notches: Sequence[float] = K.DEFAULT_NOTCHES,
    dim: int | tuple[int, ...] = -1,
    adaptive: bool = True,
    camera: str | None = None,
    low: float | None = None,
    high: float | None = None,
    floor: float = K.FUSION_FLOOR,
    gate: bool = True,
    destripe: nn.Module | None = None,
    band_weights: Sequence[float] | None = None,
    compensate_delay: bool = True,
    unit_dc: bool = True,
    max_ripple_db: float | None = MAX_RIPPLE_DB,
    **kwargs,
) -> FPNSuppression:
    """Design taps and build an :class:`FPNSuppression`: notch filter, eq. (11) fusion (when
    ``adaptive``), the stripe gate (when ``gate``), and an optional ``destripe`` module first.

    The fusion thresholds are in the camera's amplitude units: ``low`` / ``high`` when given, else
    those of the ``camera`` profile (:mod:`tof_fpn_torch.cameras`), else CamCube's (the paper's 70
    and 350). For a camera without a profile, measure them with :func:`fusion_from_data`.

    Defaults: Table I's best adaptive filter ``{20, 0.14}`` with notches at ``2pi/3`` and ``pi``,
    unit DC gain, gated. The paper's stage is ``suppression_from_design(unit_dc=False,
    gate=False)``. ``compensate_delay``, ``unit_dc``, ``max_ripple_db`` and ``kwargs`` (``border``,
    ``trainable``, ``allow_shift``) as in :func:`filter_from_design`.
    """
    filt = filter_from_design(
        order,
        rho,
        notches=notches,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
        dim=dim,
        **kwargs,
    )
    fusion = None
    if adaptive:
        lo, hi = _thresholds(camera, low, high)
        fusion = AmplitudeFusion(lo, hi, floor)
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
    dim: int | tuple[int, ...] = -1,
    camera: str | None = None,
    low: float | None = None,
    high: float | None = None,
    floor: float = K.FUSION_FLOOR,
    gate: bool = True,
    **kwargs,
) -> FPNSuppression:
    """The stage as a trainable first layer, initialised from the design.

    The notch taps train through ``G`` of ``H = A G`` with the zeros of ``A`` held
    (:func:`~tof_fpn_torch.runtime.keep_zeros`); the fusion is a
    :class:`~tof_fpn_torch.runtime.TrainableFusion` starting at the camera's thresholds (CamCube's
    by default, or ``low`` / ``high``). ``kwargs`` go to :func:`filter_from_design`. Freeze with
    :func:`tof_fpn_torch.runtime.freeze` before export.
    """
    filt = filter_from_design(order, rho, notches=notches, dim=dim, trainable=True, **kwargs)
    keep_zeros(filt, fixed_zero_taps(notches))
    lo, hi = _thresholds(camera, low, high)
    return FPNSuppression(filt, TrainableFusion(lo, hi, floor), gate=gate)
