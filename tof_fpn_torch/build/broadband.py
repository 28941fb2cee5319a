"""Builder of the broadband destriper from data: a :class:`~tof_fpn_torch.runtime.Destripe` for
the orientations whose column / row offsets the frames show."""

from __future__ import annotations

import torch

from .. import constants as K
from ..analysis.stripe_energy import column_stripe_energy, quiet_mask
from ..denoise import estimate_sigma
from ..runtime import Destripe, destripe, valid_mask
from ._checks import check_real

__all__ = [
    "AUTO_DESTRIPE_MAX_ENERGY",
    "AUTO_DESTRIPE_MIN_Z",
    "AUTO_DESTRIPE_WIDTH",
    "broadband_from_data",
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
