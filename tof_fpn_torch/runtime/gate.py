r"""Stripe gate: open the FPN stage only for frames whose stripes are really there (torch only).

A notch filter removes everything at its frequencies: fixed-pattern stripes, but also scene detail
(edges, thin objects, fine texture) and noise. On a frame without stripes it can only hurt (up to
10 dB PSNR on the detailed synthetic scenes). Stripes differ from scene detail in one way a single
frame shows: they are the same in every row (column stripes; every column for row stripes).

Statistic, per image and orientation. Let ``e = x - H x`` be what the filter removes (its
notch-band content) on the valid pixels. With a robust scale ``s`` of ``e`` (three rounds of
clipped mean absolute value, ``1.2533 mean|e|`` over ``|e| <= 3 s``: no sort, exportable), keep
the pixels with ``|e| <= 3 s`` (edges of objects and thin high-contrast bars drop out) and average
``e`` down every column: the profile ``p(x)`` over ``n(x)`` kept rows. Stripes survive the
average; noise and scene detail that is not the same in every row average down to variance
``s^2 / n(x)``. So::

    T = sum_x p(x)^2 / sum_x (s^2 / n(x))          ~ chi^2_nu / nu without stripes

with ``nu = W g_e`` degrees of freedom, ``g_e = ||delta - h||^2`` the white-noise power gain of
``I - H`` (the fraction of the band the notches remove). The gate opens above the
false-alarm threshold ``T_a`` of ``chi^2_nu / nu`` at probability ``a`` = 1e-3 per image
(:data:`~tof_fpn_torch.constants.GATE_Z`, Wilson-Hilferty), fully at
``2 T_a``, and only when the stripe amplitude ``sqrt(mean p^2 - mean s^2/n)`` is at least
``min_stripe`` (:data:`~tof_fpn_torch.constants.GATE_MIN_STRIPE`, 0.1) times the per-pixel
noise ``s / sqrt(g_e)`` (fully at twice that): a stripe far below
the noise is not worth what the filter does to the scene. Both ramps are linear, so the output is
a continuous function of the input. ``g`` is per image, in ``[0, 1]``; the stage returns
``x + g (stage(x) - x)``.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K

__all__ = ["chi2_upper_quantile", "stripe_gate"]


def chi2_upper_quantile(dof: torch.Tensor, z: float = K.GATE_Z) -> torch.Tensor:
    """Upper quantile of ``chi^2_dof / dof`` at the standard normal quantile ``z``
    (Wilson-Hilferty; tensor arithmetic, so it traces with symbolic sizes)."""
    c = 2.0 / (9.0 * dof.clamp_min(1.0))
    return (1.0 - c + z * c.sqrt()) ** 3


def _robust_scale(e: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """(B, 1, 1, 1) robust standard deviation of ``e`` over ``keep``: clipped mean |e|."""
    a = torch.where(keep, e.abs(), torch.zeros_like(e))
    n = keep.sum((-3, -2, -1), keepdim=True).clamp_min(1).to(e.dtype)
    s = 1.2533141373155003 * a.sum((-3, -2, -1), keepdim=True) / n  # sqrt(pi/2) mean|e|
    for _ in range(3):
        inside = keep & (a <= 3.0 * s)
        m = inside.sum((-3, -2, -1), keepdim=True).clamp_min(1).to(e.dtype)
        # E|e| of a normal clipped at 3 sigma is 0.7866 sigma (instead of 0.7979)
        s = torch.where(inside, a, torch.zeros_like(a)).sum((-3, -2, -1), keepdim=True) / (
            0.786619 * m
        )
    return s.clamp_min(1e-30)


def _statistic(
    e: torch.Tensor, keep: torch.Tensor, s: torch.Tensor, avg_dim: int, gain: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(T, stripe rms / pixel noise, profile length)`` per image for profiles averaged along
    ``avg_dim``."""
    k = keep & (e.abs() <= 3.0 * s)
    n = k.sum(avg_dim, keepdim=True).to(e.dtype)
    p = torch.where(k, e, torch.zeros_like(e)).sum(avg_dim, keepdim=True) / n.clamp_min(1.0)
    has = n > 0
    expected = torch.where(has, s * s / n.clamp_min(1.0), torch.zeros_like(n))
    power = (p * p).sum((-3, -2, -1), keepdim=True)
    noise = expected.sum((-3, -2, -1), keepdim=True).clamp_min(1e-30)
    cols = has.sum((-3, -2, -1), keepdim=True).clamp_min(1).to(e.dtype)
    stripe = ((power - noise) / cols).clamp_min(0.0).sqrt()
    return power / noise, stripe / (s / math.sqrt(max(gain, 1e-12))), cols


def stripe_gate(
    x: torch.Tensor,
    filtered: torch.Tensor,
    valid: torch.Tensor | None,
    dims: list[int],
    gain: float,
    min_stripe: float = K.GATE_MIN_STRIPE,
) -> torch.Tensor:
    """Per-image gate in ``[0, 1]`` (shape (B, 1, 1, 1)) for a filter with noise gain ``gain``.

    Args:
        x: (B, 1, H, W) depth (invalid pixels filled or not; they are masked out).
        filtered: (B, 1, H, W) the filter's output ``H x``.
        valid: (B, 1, H, W) bool or None (all valid).
        dims: the filtering dimensions (-1: column stripes, -2: row stripes).
        gain: ``||delta - h||^2`` of the taps (white-noise power gain of ``I - H``).
        min_stripe: smallest stripe amplitude, in units of the per-pixel noise, that opens the
            gate (fully at twice that).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> x = 2.0 + 0.01 * torch.randn(1, 1, 64, 96, generator=g)
        >>> flat = torch.full_like(x, 2.0)  # a "filter" that removed only noise
        >>> float(stripe_gate(x, flat, None, [-1], 1.0))
        0.0
    """
    e = x - filtered
    keep = torch.isfinite(e) if valid is None else valid & torch.isfinite(e)
    e = torch.where(keep, e, torch.zeros_like(e))
    s = _robust_scale(e, keep)
    gate = torch.zeros_like(s)
    for d in dims:
        avg_dim = -2 if d == -1 else -1  # column stripes: average down the columns
        t, ratio, cols = _statistic(e, keep, s, avg_dim, gain)
        t_a = chi2_upper_quantile(cols * gain)
        g = ((t - t_a) / t_a).clamp(0.0, 1.0)
        if min_stripe > 0:
            g = g * ((ratio - min_stripe) / min_stripe).clamp(0.0, 1.0)
        gate = torch.maximum(gate, g)
    return gate
