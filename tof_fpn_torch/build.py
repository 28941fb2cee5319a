r"""Builders: run-time modules from an offline design or from data (the layer above both).

The run-time package (:mod:`tof_fpn_torch.runtime`) takes filter taps and knows nothing of how they
were designed; the design package (:mod:`tof_fpn_torch.design`) produces taps and knows nothing of
torch. These factories join them: they design the taps (NumPy / SciPy), or first estimate the
stripes in data (:mod:`tof_fpn_torch.analysis`), then build the torch modules and record on them
what the design was (``order``, ``rho``, ``notches``, which TorchScript and ONNX exports keep).

Example:
    >>> stage = suppression_from_design(20, 0.14)
    >>> stage.filter.order, stage.filter.rho, stage.filter.taps.shape, stage.gate
    (20, 0.14, torch.Size([21]), True)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from . import constants as K
from .analysis.stripe_energy import column_stripe_energy, structure_mask
from .analysis.stripes import StripeEstimate, estimate_stripes
from .cameras import profile
from .denoise import estimate_noise_k, estimate_sigma
from .design import compensate_half_sample, design_fpn, fixed_zero_taps, max_rho
from .runtime import (
    AmplitudeFusion,
    Destripe,
    FPNFilter,
    FPNSuppression,
    TrainableFusion,
    destripe,
    keep_zeros,
    valid_mask,
)

__all__ = [
    "MAX_RIPPLE_DB",
    "broadband_from_data",
    "trainable_suppression",
    "filter_from_design",
    "fusion_from_data",
    "suppression_from_data",
    "suppression_from_design",
]


#: The builders refuse designs whose passband ripple is worse than this (dB): such a "notch filter"
#: changes the scene more than it removes stripes (e.g. 0 dB ripple with H(0) = 2 doubles depth).
MAX_RIPPLE_DB = -20.0


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
        # the interpolator's band reaches the top passband edge (at most 0.95 pi)
        taps = compensate_half_sample(
            taps, band_edge=float(min(design.bands[-1, 1], 0.95 * math.pi))
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
    """Design taps with :func:`tof_fpn_torch.design.design_fpn` and build an :class:`FPNFilter`.

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


def fusion_from_data(
    depth: torch.Tensor, amplitude: torch.Tensor, floor: float = K.FUSION_FLOOR
) -> AmplitudeFusion:
    """Eq. (11) fusion with thresholds measured on the data, in its own amplitude units.

    Rule (:mod:`tof_fpn_torch.cameras`): fit the depth-noise law ``sigma_D = k / A`` (eq. 2;
    :func:`~tof_fpn_torch.denoise.estimate_noise_k`, wavelet MAD over all frames' valid pixels)
    and place ``low`` and ``high`` where the relative noise ``k / (A D)``, ``D`` the median valid
    depth, is :data:`~tof_fpn_torch.constants.FUSION_LOW_RELATIVE_NOISE` (4 %) and
    ``FUSION_HIGH_RELATIVE_NOISE`` (0.8 %): the paper's 70 / 350 on its own synthetic data.

    Args:
        depth, amplitude: (B, 1, H, W) frames of one camera (depth in any unit).
        floor: the fusion's weight of the filtered depth for strong signals.

    Raises:
        ValueError: no valid pixel, or no noise measurable (``k = 0``).
    """
    valid = valid_mask(depth, amplitude)
    if not bool(valid.any()):
        raise ValueError("fusion_from_data: no valid pixel (depth > 0 finite, amplitude >= 0)")
    k = float(estimate_noise_k(depth.double(), amplitude.double(), valid=valid).mean())
    med = float(depth[valid].double().median())
    if not (k > 0 and med > 0):
        raise ValueError(f"fusion_from_data: cannot measure the noise law (k = {k}, D = {med})")
    low = k / (K.FUSION_LOW_RELATIVE_NOISE * med)
    high = k / (K.FUSION_HIGH_RELATIVE_NOISE * med)
    return AmplitudeFusion(low, high, floor)


def suppression_from_data(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None = None,
    order: int = K.DEFAULT_ORDER,
    rho: float | None = None,
    *,
    false_alarm: float = K.DETECTION_FALSE_ALARM,
    estimate_kwargs: dict | None = None,
    **kwargs,
) -> FPNSuppression:
    """A stage with the pieces the data call for (never one the data do not).

    Broadband column / row offsets: a :class:`~tof_fpn_torch.runtime.Destripe` for the orientations
    :func:`broadband_from_data` finds (pass ``destripe=`` to choose yourself, None for none). The
    periodic components :func:`~tof_fpn_torch.analysis.estimate_stripes` reports (false-alarm
    probability ``<= false_alarm``, amplitude over its noise floor) become the notches, their
    orientations ``dim`` (both orientations share one notch set; rho defaults to
    ``min(DEFAULT_RHO, 0.9 max_rho)``). With amplitudes the fusion thresholds are measured too
    (:func:`fusion_from_data`). When nothing is found the stage has no notch and returns its
    input unchanged. The estimate is kept in ``module.estimate``; ``kwargs`` go to
    :func:`suppression_from_design`.
    """
    est: StripeEstimate = estimate_stripes(
        frames, amplitudes, false_alarm=false_alarm, **(estimate_kwargs or {})
    )
    auto_destripe = "destripe" not in kwargs
    if not est.components:
        found = broadband_from_data(frames, amplitudes) if auto_destripe else kwargs["destripe"]
        module = FPNSuppression(None, None, destripe=found)
        module.estimate = est
        return module
    merged: list[float] = []
    for f in sorted({c.frequency for c in est.components}):  # one notch for peaks < 0.02 rad apart
        if merged and f - merged[-1] < 0.02:
            continue
        merged.append(f)
    dims = sorted({c.dim for c in est.components})
    if rho is None:
        rho = min(K.DEFAULT_RHO, 0.9 * max_rho(merged))
    kwargs.setdefault("dim", tuple(dims) if len(dims) > 1 else dims[0])
    if amplitudes is None:
        kwargs.setdefault("adaptive", False)
    elif kwargs.get("adaptive", True) and "low" not in kwargs and "camera" not in kwargs:
        fusion = fusion_from_data(frames, amplitudes)
        kwargs.update(low=fusion.low, high=fusion.high)
    kwargs.setdefault("destripe", None)
    module = suppression_from_design(order, rho, notches=tuple(merged), **kwargs)
    if auto_destripe:  # what the notch stage leaves: broadband offsets, if any
        with torch.no_grad():
            notched = module(frames, amplitudes)
        module.destripe = broadband_from_data(notched, amplitudes)
    module.estimate = est
    return module


def broadband_from_data(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None = None,
    min_stripe: float = K.GATE_MIN_STRIPE,
) -> Destripe | None:
    """A :class:`~tof_fpn_torch.runtime.Destripe` for the orientations with broadband offsets in
    ``frames``, or None.

    Rule, per orientation: the destriper (whose cross-validated shrinkage leaves most stripe-free
    frames alone) must (1) move the valid pixels by an RMS of at least ``min_stripe`` times the
    frames' per-pixel noise (wavelet MAD, :func:`~tof_fpn_torch.denoise.estimate_sigma`; the floor
    of the periodic detection and the stripe gate) and (2) halve the column-stripe energy
    (:func:`~tof_fpn_torch.analysis.column_stripe_energy`, the covariance of the top and bottom
    halves' column profiles) measured away from scene structure (``structure_mask`` at 6 noise
    sigmas): what it removes must be an offset of the whole column where the scene is quiet, not a
    thin object or texture the same in both halves (the destriper alone cannot tell those apart).
    """
    valid = valid_mask(frames, amplitudes)
    if not bool(valid.any()):
        return None
    x = torch.where(valid, frames, torch.zeros_like(frames)).double()
    noise = float(estimate_sigma(x, valid=valid).mean())
    if not noise > 0:
        return None
    dims = []
    for d in (-1, -2):
        out = destripe(frames, amplitudes, dim=d)
        change = torch.where(valid, out - frames, 0.0)
        rms = float(change.double().pow(2).sum() / valid.sum()) ** 0.5
        if rms < min_stripe * noise:
            continue
        before = torch.where(valid, frames, torch.nan)
        after = torch.where(valid, out, torch.nan)
        if d == -2:  # row offsets: the same measurement on the transposed frames
            before, after = before.transpose(-1, -2), after.transpose(-1, -2)
        quiet = structure_mask(before, 6.0 * noise)
        e0 = float(column_stripe_energy(before, quiet).covariance.mean())
        e1 = float(column_stripe_energy(after, quiet).covariance.mean())
        if e0 > 0 and e1 <= 0.5 * e0:
            dims.append(d)
    if not dims:
        return None
    return Destripe(dim=tuple(dims) if len(dims) > 1 else dims[0])


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
