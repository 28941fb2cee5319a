"""Builders from data: the pieces of the FPN stage that calibration frames call for, measured with
:mod:`tof_fpn_torch.analysis` (periodic stripes -> notches, their strength against the amplitude
-> the eq. (11) fusion and the gate's stripe scale, broadband column / row offsets -> a
destriper)."""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from typing import Literal

import torch
from torch import nn

from .. import constants as K
from ..analysis.stripe_energy import column_stripe_energy, quiet_mask
from ..analysis.stripe_fusion import MIN_BIN_PIXELS, fit_fusion, stripe_power_by_amplitude
from ..analysis.stripes import StripeEstimate, estimate_stripes
from ..cameras import profile
from ..denoise import estimate_noise_k, estimate_sigma
from ..design import max_rho
from ..runtime import AmplitudeFusion, Destripe, FPNFilter, FPNSuppression, destripe, valid_mask
from ..runtime.gate import line_gate
from ._checks import (
    check_dim,
    check_filter_options,
    check_flag,
    check_fusion_options,
    check_keys,
    check_order,
    check_real,
    check_rho,
)
from .design import (
    DEFAULT_ALLOW_SHIFT,
    DEFAULT_BORDER,
    DEFAULT_COMPENSATE_DELAY,
    DEFAULT_GATE,
    DEFAULT_TRAINABLE,
    DEFAULT_UNIT_DC,
    MAX_RIPPLE_DB,
    filter_from_design,
    suppression_from_design,
)

__all__ = [
    "AUTO",
    "AUTO_DESTRIPE_MAX_ENERGY",
    "AUTO_DESTRIPE_MIN_Z",
    "AUTO_DESTRIPE_WIDTH",
    "ESTIMATE_OPTIONS",
    "NOTCH_MERGE",
    "RHO_SHARE",
    "STRIPE_SCALE_RANGE",
    "broadband_from_data",
    "fusion_from_data",
    "fusion_from_noise",
    "suppression_from_data",
]


#: The high-pass width of the destriper :func:`broadband_from_data` builds (pixels): offsets that
#: change more slowly along the line are left alone. Scene shapes that span the frame (a wall's
#: curvature above a row of objects) pass the destriper's cross-validation as offsets at the
#: destriper's own default of 31 (-3.1 dB on a stripe-free 204 x 204 synthetic scene, -0.05 dB at
#: 15); the ADI wall's broadband offsets are removed by 13.4 dB at 15 (14.5 at 31).
AUTO_DESTRIPE_WIDTH = 15
#: :func:`broadband_from_data` needs the column profiles of the frames' two halves to correlate at
#: ``r sqrt(n) >=`` this (in null standard deviations)
AUTO_DESTRIPE_MIN_Z = 4.0
#: ... and to leave at most this share of the column-stripe energy away from scene structure
AUTO_DESTRIPE_MAX_ENERGY = 0.5
#: :func:`suppression_from_data`: detected frequencies closer than this (radians per sample)
#: become one notch ...
NOTCH_MERGE = 0.02
#: ... and without a given ``rho`` the design takes ``min(DEFAULT_RHO, RHO_SHARE * max_rho)`` of
#: the notches (a margin below the largest transition width they allow)
RHO_SHARE = 0.9
#: The range the gate's ``stripe_scale`` measured on calibration frames is clamped to
STRIPE_SCALE_RANGE = (0.25, 8.0)


def fusion_from_data(
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    filter: FPNFilter | None = None,
) -> AmplitudeFusion:
    """Eq. (11) fusion fitted to the stripes the notch ``filter`` removes, in the data's units.

    Rule (:mod:`tof_fpn_torch.analysis.stripe_fusion`): in amplitude bins, the stripe power ``S``
    (the part of the filter's change that is the same down the columns, from the two halves of the
    rows), the noise power ``sigma^2`` and the change's power ``E[D^2]`` give the weight of least
    error ``w* = (S + (1 - h_0) sigma^2) / E[D^2]``; ``low``, ``high`` and ``floor`` are fitted
    to it by the excess squared error. So the thresholds follow the stripes' own strength
    against the amplitude (falling as ``1 / A``, ``exp(-A / a)`` or not at all), whatever the
    camera's amplitude scale. The bins are kept in ``module.bins``.

    Args:
        depth, amplitude: (B, 1, H, W) frames of one camera (depth in any unit).
        filter: the notch filter of the stage (default: :func:`filter_from_design`'s).

    Raises:
        ValueError: ``filter`` is not an :class:`FPNFilter`, or fewer valid pixels than two
            amplitude bins need (use :func:`fusion_from_noise` or a camera profile's thresholds).
    """
    if filter is not None and not isinstance(filter, FPNFilter):
        raise ValueError(f"filter must be an FPNFilter or None, got {type(filter).__name__}")
    filt = filter_from_design() if filter is None else filter
    bins = stripe_power_by_amplitude(depth, amplitude, filt)
    if bins is None:
        raise ValueError(
            "fusion_from_data: too few valid pixels to measure the stripes against the amplitude "
            f"(need {2 * MIN_BIN_PIXELS}); use fusion_from_noise or a camera profile"
        )
    low, high, floor = fit_fusion(bins)
    fusion = AmplitudeFusion(low, high, floor)
    fusion.bins = bins
    return fusion


def fusion_from_noise(
    depth: torch.Tensor, amplitude: torch.Tensor, floor: float = K.FUSION_FLOOR
) -> AmplitudeFusion:
    """Eq. (11) fusion with thresholds where the data's relative depth noise is the paper's.

    Rule (:mod:`tof_fpn_torch.cameras`): fit the depth-noise law ``sigma_D = k / A`` (eq. 2;
    :func:`~tof_fpn_torch.denoise.estimate_noise_k`, wavelet MAD over all frames' valid pixels)
    and place ``low`` and ``high`` where the relative noise ``k / (A D)``, ``D`` the median valid
    depth, is :data:`~tof_fpn_torch.constants.FUSION_LOW_RELATIVE_NOISE` (4 %) and
    ``FUSION_HIGH_RELATIVE_NOISE`` (0.8 %): the paper's 70 / 350 on its own synthetic data. It
    transfers the paper's thresholds to another amplitude scale (the camera profiles); it does
    not look at the stripes, so on stripes that do not follow the paper's law it gates them
    wrongly: use :func:`fusion_from_data` there.

    Args:
        depth, amplitude: (B, 1, H, W) frames of one camera (depth in any unit).
        floor: the fusion's weight of the filtered depth for strong signals.

    Raises:
        ValueError: ``floor`` outside ``[0, 1]``, no valid pixel, or no noise measurable
            (``k = 0``).
    """
    check_real("floor", floor, minimum=0.0, maximum=1.0)
    valid = valid_mask(depth, amplitude)
    if not bool(valid.any()):
        raise ValueError("fusion_from_noise: no valid pixel (depth > 0 finite, amplitude >= 0)")
    k = float(estimate_noise_k(depth.double(), amplitude.double(), valid=valid).mean())
    med = float(depth[valid].double().median())
    if not (k > 0 and med > 0):
        raise ValueError(f"fusion_from_noise: cannot measure the noise law (k = {k}, D = {med})")
    low = k / (K.FUSION_LOW_RELATIVE_NOISE * med)
    high = k / (K.FUSION_HIGH_RELATIVE_NOISE * med)
    return AmplitudeFusion(low, high, floor)


def _stripe_scale(module: FPNSuppression, depth: torch.Tensor, amplitude: torch.Tensor) -> float:
    """The factor that makes the gate's stripe power (read off each frame's column profile) equal
    the weighted stripe power the fusion's bins measured on the same frames (see
    :class:`~tof_fpn_torch.runtime.FPNSuppression`, ``stripe_scale``), within
    :data:`STRIPE_SCALE_RANGE`."""
    bins = None if module.fusion is None else module.fusion.bins
    filt = module.filter
    if bins is None or filt is None or not bool((bins.stripe_power > 0).any()):
        return 1.0
    with torch.no_grad():
        x = depth.double()
        valid = valid_mask(x, amplitude)
        filtered = filt(x, valid)
        _, read = line_gate(x, filtered, valid, filt.dims, filt.notches, module.noise_gain)
        weight = torch.where(valid, module.fusion.weight(amplitude.double()), 0.0)
        read_total = float((read * weight).sum())
    measured = float((bins.pixels * module.fusion.weight(bins.amplitude) * bins.stripe_power).sum())
    if not read_total > 0:
        return 1.0
    lo, hi = STRIPE_SCALE_RANGE
    return min(max(measured / read_total, lo), hi)


#: ``destripe`` of :func:`suppression_from_data` that measures the broadband offsets on the frames
AUTO = "auto"
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

    Broadband column / row offsets: a :class:`~tof_fpn_torch.runtime.Destripe` for the orientations
    :func:`broadband_from_data` finds in what the notch stage leaves. The periodic components
    :func:`~tof_fpn_torch.analysis.estimate_stripes` reports (false-alarm probability ``<=
    false_alarm``, amplitude over its noise floor) become the notches (frequencies closer than
    :data:`NOTCH_MERGE` one notch), their orientations ``dim`` (both orientations share one notch
    set). With amplitudes the fusion is fitted to the stripes' strength against the amplitude
    (:func:`fusion_from_data`) and the gate's stripe power is calibrated on the same frames
    (``stripe_scale`` of :class:`~tof_fpn_torch.runtime.FPNSuppression`). When nothing is found
    the stage has no notch and returns its input unchanged. The estimate is kept in
    ``module.estimate``; the stage is built by :func:`suppression_from_design`.

    Args:
        frames: (B, 1, H, W) calibration depth frames of one camera (any unit); they share one
            fixed pattern.
        amplitudes: (B, 1, H, W) their amplitudes, or None (no fusion measured).
        order: the notch filter's order (default Table I's 20).
        rho: the transition half-width (fraction of ``pi``); default ``min(DEFAULT_RHO, RHO_SHARE
            max_rho)`` of the notches found (:data:`RHO_SHARE` 0.9 of the largest they allow).
        false_alarm: largest false-alarm probability of a reported stripe (default 0.01).
        estimate_kwargs: further options of :func:`~tof_fpn_torch.analysis.estimate_stripes`
            (keys from :data:`ESTIMATE_OPTIONS`), or None.
        camera_hint: the camera profile whose thresholds the fusion takes where the frames are
            too small to measure the stripes on (else the noise rule, :func:`fusion_from_noise`).
        dim: the notch filter's orientation; default (None) the orientations of the stripes found.
        adaptive: blend by amplitude (eq. 11); default (None) when ``amplitudes`` are given.
        camera: the camera profile whose fusion thresholds to use instead of measuring them.
        low, high: the fusion's thresholds instead of measuring them (a ``high`` without ``low``
            or ``camera`` replaces the measured ``high`` only).
        floor: the fusion's weight of the filtered depth for strong signals where it is not
            fitted (given thresholds, a camera profile, the noise rule; default 0.2); a fitted
            fusion has its own.
        gate: the per-frame stripe gate (default True).
        destripe: ``"auto"`` (default): a :class:`~tof_fpn_torch.runtime.Destripe` where
            :func:`broadband_from_data` finds broadband offsets; None for none; or the module to
            run first.
        border, trainable, allow_shift, band_weights, compensate_delay, unit_dc, max_ripple_db:
            as in :func:`filter_from_design`.

    Raises:
        ValueError: an option is invalid (the message names it, its value and what is allowed),
            or the frames or the design are (see :func:`~tof_fpn_torch.analysis.estimate_stripes`
            and :func:`suppression_from_design`).
    """
    order = check_order(order)
    rho = check_rho(rho, optional=True)
    estimate_options = check_keys("estimate_kwargs", estimate_kwargs, ESTIMATE_OPTIONS)
    if camera_hint is not None and not isinstance(camera_hint, str):
        raise ValueError(
            f"camera_hint must be a camera profile's name or None, got {camera_hint!r}"
        )
    check_dim(dim, optional=True)
    check_filter_options(border, trainable, allow_shift, compensate_delay, unit_dc, max_ripple_db)
    if adaptive is not None:
        check_flag("adaptive", adaptive)
    check_fusion_options(camera, low, high, floor)
    check_flag("gate", gate)
    auto_destripe = isinstance(destripe, str) and destripe == AUTO
    if not (auto_destripe or destripe is None or isinstance(destripe, nn.Module)):
        raise ValueError(f"destripe must be {AUTO!r}, None or an nn.Module, got {destripe!r}")

    est: StripeEstimate = estimate_stripes(
        frames, amplitudes, false_alarm=false_alarm, **estimate_options
    )
    if not est.components:
        found = broadband_from_data(frames, amplitudes) if auto_destripe else destripe
        module = FPNSuppression(None, None, destripe=found)
        module.estimate = est
        return module
    merged: list[float] = []
    for f in sorted({c.frequency for c in est.components}):  # one notch for close peaks
        if merged and f - merged[-1] < NOTCH_MERGE:
            continue
        merged.append(f)
    notches = tuple(merged)
    if dim is None:
        dims = sorted({c.dim for c in est.components})
        dim = tuple(dims) if len(dims) > 1 else dims[0]
    if rho is None:
        rho = min(K.DEFAULT_RHO, RHO_SHARE * max_rho(notches))
    if adaptive is None:
        adaptive = amplitudes is not None
    measured = None
    if amplitudes is not None and adaptive and low is None and camera is None:
        filt = filter_from_design(
            order,
            rho,
            notches=notches,
            dim=dim,
            border=border,
            allow_shift=allow_shift,
            band_weights=band_weights,
            compensate_delay=compensate_delay,
            unit_dc=unit_dc,
            max_ripple_db=max_ripple_db,
        )
        measured = _measured_fusion(frames, amplitudes, filt, floor=floor, camera_hint=camera_hint)
        low, floor = measured.low, measured.floor
        high = measured.high if high is None else high
    module = suppression_from_design(
        order,
        rho,
        notches=notches,
        dim=dim,
        adaptive=adaptive,
        camera=camera,
        low=low,
        high=high,
        floor=floor,
        gate=gate,
        destripe=None if auto_destripe else destripe,
        border=border,
        trainable=trainable,
        allow_shift=allow_shift,
        band_weights=band_weights,
        compensate_delay=compensate_delay,
        unit_dc=unit_dc,
        max_ripple_db=max_ripple_db,
    )
    if measured is not None:
        module.fusion.bins = measured.bins
        module.stripe_scale = _stripe_scale(module, frames, amplitudes)
    if auto_destripe:  # what the notch stage leaves: broadband offsets, if any
        with torch.no_grad():
            notched = module(frames, amplitudes)
        module.destripe = broadband_from_data(notched, amplitudes)
    module.estimate = est
    return module


def _measured_fusion(
    frames: torch.Tensor,
    amplitudes: torch.Tensor,
    filt: FPNFilter,
    *,
    floor: float,
    camera_hint: str | None,
) -> AmplitudeFusion:
    """:func:`fusion_from_data` with the stage's own notch filter ``filt``; where the frames are
    too small to measure the stripes on, the thresholds of the ``camera_hint`` profile, else the
    noise rule (:func:`fusion_from_noise`), with ``floor``."""
    try:
        return fusion_from_data(frames, amplitudes, filt)
    except ValueError:
        prof = None if camera_hint is None else profile(camera_hint)
        if prof is not None and prof.fusion_low is not None and prof.fusion_high is not None:
            return AmplitudeFusion(prof.fusion_low, prof.fusion_high, floor)
        return fusion_from_noise(frames, amplitudes, floor)


def broadband_from_data(
    frames: torch.Tensor,
    amplitudes: torch.Tensor | None = None,
    min_stripe: float = K.GATE_MIN_STRIPE,
    width: int = AUTO_DESTRIPE_WIDTH,
) -> Destripe | None:
    """A :class:`~tof_fpn_torch.runtime.Destripe` for the orientations with broadband offsets in
    ``frames``, or None.

    Rule, per orientation: the destriper (whose cross-validated shrinkage leaves most stripe-free
    frames alone) must (1) move the valid pixels by an RMS of at least ``min_stripe`` times the
    frames' per-pixel noise (wavelet MAD, :func:`~tof_fpn_torch.denoise.estimate_sigma`; the floor
    of the periodic detection and the stripe gate) and (2) halve the column-stripe energy
    (:data:`AUTO_DESTRIPE_MAX_ENERGY`; :func:`~tof_fpn_torch.analysis.column_stripe_energy`, the
    covariance of the top and bottom halves' column profiles) measured away from scene structure
    (:func:`quiet_mask`): what it removes must be an offset of the whole column where the scene
    is quiet, not a thin object or texture the same in both halves (the destriper alone cannot
    tell those apart); and (3) the two halves' profiles there must correlate significantly:
    ``r sqrt(n) >=`` :data:`AUTO_DESTRIPE_MIN_Z` over ``n`` columns (no common pattern gives
    ``r ~ N(0, 1 / n)``; the ADI wall's columns give 20, stripe-free frames where (1) and (2)
    passed by chance 0.3-0.5).

    Args:
        frames: (B, 1, H, W) depth frames of one camera (any unit).
        amplitudes: (B, 1, H, W) their amplitudes (for the valid pixels), or None.
        min_stripe: the smallest RMS change, in units of the frames' per-pixel noise, that counts
            (default :data:`~tof_fpn_torch.constants.GATE_MIN_STRIPE`, 0.1).
        width: the destriper's high-pass width, pixels (an int >= 3; default
            :data:`AUTO_DESTRIPE_WIDTH`, 15).

    Raises:
        ValueError: ``min_stripe`` or ``width`` is invalid.
    """
    check_real("min_stripe", min_stripe, minimum=0.0)
    if isinstance(width, bool) or not isinstance(width, int) or width < 3:
        raise ValueError(f"width must be an int >= 3 (pixels), got {width!r}")
    valid = valid_mask(frames, amplitudes)
    if not bool(valid.any()):
        return None
    x = torch.where(valid, frames, torch.zeros_like(frames)).double()
    noise = float(estimate_sigma(x, valid=valid).mean())
    if not noise > 0:
        return None
    dims = []
    for d in (-1, -2):
        out = destripe(frames, amplitudes, dim=d, width=width)
        change = torch.where(valid, out - frames, 0.0)
        rms = float(change.double().pow(2).sum() / valid.sum()) ** 0.5
        if rms < min_stripe * noise:
            continue
        before = torch.where(valid, frames, torch.nan)
        after = torch.where(valid, out, torch.nan)
        if d == -2:  # row offsets: the same measurement on the transposed frames
            before, after = before.transpose(-1, -2), after.transpose(-1, -2)
        quiet = quiet_mask(before)
        energy = column_stripe_energy(before, quiet)
        e0 = float(energy.covariance.mean())
        e1 = float(column_stripe_energy(after, quiet).covariance.mean())
        z = float((energy.correlation * energy.columns.double().sqrt()).nan_to_num(0.0).min())
        if e0 > 0 and e1 <= AUTO_DESTRIPE_MAX_ENERGY * e0 and z >= AUTO_DESTRIPE_MIN_Z:
            dims.append(d)
    if not dims:
        return None
    return Destripe(dim=tuple(dims) if len(dims) > 1 else dims[0], width=width)
