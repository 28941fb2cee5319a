"""Builders of the eq. (11) fusion from data: thresholds fitted to the stripes the notch filter
removes (:func:`fusion_from_data`) or placed by the depth-noise law (:func:`fusion_from_noise`),
and the gate's stripe scale calibrated on the same frames."""

from __future__ import annotations

import torch

from .. import constants as K
from ..analysis.stripe_fusion import MIN_BIN_PIXELS, fit_fusion, stripe_power_by_amplitude
from ..cameras import profile
from ..denoise import estimate_noise_k
from ..runtime import AmplitudeFusion, FPNFilter, FPNSuppression, valid_mask
from ..runtime.gate import line_gate
from ._checks import check_real
from .design import filter_from_design

__all__ = ["STRIPE_SCALE_RANGE", "fusion_from_data", "fusion_from_noise"]


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


def measure_fusion(
    module: FPNSuppression,
    frames: torch.Tensor,
    amplitudes: torch.Tensor,
    *,
    high: float | None,
    floor: float,
    camera_hint: str | None,
) -> None:
    """Give ``module`` the fusion measured on the frames with its own notch filter
    (:func:`fusion_from_data`; ``high`` replaces the measured one when given) and calibrate its
    gate's ``stripe_scale`` on them. Where the frames are too small to measure the stripes on,
    the thresholds of the ``camera_hint`` profile, else the noise rule
    (:func:`fusion_from_noise`), with ``floor``."""
    try:
        measured = fusion_from_data(frames, amplitudes, module.filter)
    except ValueError:
        prof = None if camera_hint is None else profile(camera_hint)
        if prof is not None and prof.fusion_low is not None and prof.fusion_high is not None:
            measured = AmplitudeFusion(prof.fusion_low, prof.fusion_high, floor)
        else:
            measured = fusion_from_noise(frames, amplitudes, floor)
    fusion = AmplitudeFusion(measured.low, measured.high if high is None else high, measured.floor)
    fusion.bins = measured.bins
    module.fusion = fusion
    module.stripe_scale = _stripe_scale(module, frames, amplitudes)
