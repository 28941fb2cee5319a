"""The noise law of the diagnosing model: decoding of the noise-free samples and the spread of
the decoded amplitude and depth.

The noise of one sample is ``v = B / g + (sigma_read / g)^2 + 1/12`` DN^2, so each component of
``X_1 (2/N)`` has standard deviation ``s = sqrt(2 v / N)``: the amplitude is Rician (mean and
spread from ``A_0`` and ``s``), the depth Gaussian with ``sigma_D = (c_L / 4 pi f) s / A_0``
(eq. 2). Samples with unequal variances (a term changed them, e.g. the clip of ``saturation``)
get the delta method through eq. (1), across and along the phasor.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K

__all__ = ["clipped_noise", "decode_flat_safe", "noise_law", "rician"]


class _Laguerre(torch.autograd.Function):
    """``f(x) = e^-x ((1 + 2x) I_0(x) + 2x I_1(x))`` (``L_1/2(-2x)``), with ``f'(x) = i0e(x) +
    i1e(x)``: from ``I_0' = I_1`` and ``I_1' = I_0 - I_1 / x``,
    ``f' = -f + e^-x ((2 + 2x) I_0 + (1 + 2x) I_1) = e^-x (I_0 + I_1)``. The two Bessel
    functions of the forward pass are kept for the backward one (autograd through
    ``torch.special.i0e`` / ``i1e`` evaluates both again)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        i0, i1 = torch.special.i0e(x), torch.special.i1e(x)
        ctx.save_for_backward(i0 + i1)
        return (1 + 2 * x) * i0 + 2 * x * i1

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (slope,) = ctx.saved_tensors
        return grad * slope


def rician(a0: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean and sd of ``|a0 + s (xi_1 + j xi_2)|``: the mean is
    ``s sqrt(pi / 2) L_1/2(-a0^2 / 2 s^2)`` (:class:`_Laguerre`)."""
    x = a0 * a0 / (4.0 * s * s)
    mean = s * math.sqrt(math.pi / 2) * _Laguerre.apply(x)
    var = (a0 * a0 + 2 * s * s - mean * mean).clamp_min(1e-3 * s * s)
    return mean, torch.sqrt(var)


def noise_law(cam, v: dict, dn, a0, offset, sample_var):
    """``(mu_a, sd_a, var_d, s)`` for camera ``cam``: the Rician amplitude mean and sd, the depth
    variance (eq. 2) and the sd of one component of ``(2/N) X_1``, from shot, read and
    quantisation noise of the samples ``dn`` (with the unequal variances ``sample_var``, e-^2,
    of samples a term changed, when given)."""
    g = v["camera.conversion_gain"]
    k_d = K.SPEED_OF_LIGHT_AIR / (4 * math.pi * float(cam.modulation_frequency))
    if sample_var is None:
        var = offset.clamp_min(0) / g + (v["camera.read_noise"] / g) ** 2 + 1.0 / 12.0
        s = torch.sqrt(2.0 * var / cam.n_phases)
        mu_a, sd_a = rician(a0, s)
        var_d = (k_d * s / a0) ** 2
    else:
        s_perp, s_par = clipped_noise(dn, sample_var / g**2 + 1.0 / 12.0)
        s = torch.sqrt(0.5 * (s_perp**2 + s_par**2))
        mu_a, sd_a = rician(a0, s)
        sd_a = sd_a * s_par / s
        var_d = (k_d * s_perp / a0) ** 2
    return mu_a, sd_a, var_d, s


def _phasor(dn: torch.Tensor):
    """``Re X_1``, ``Im X_1`` (1, 1, H, W; float64), the DFT weights (exact zeros), and where
    the samples are flat (X_1 = 0)."""
    n = dn.shape[1]
    th = torch.arange(n, dtype=torch.float64) * (2 * math.pi / n)
    c, sn = torch.cos(th), torch.sin(th)
    c, sn = [torch.where(x.abs() < 1e-12, torch.zeros_like(x), x).view(1, n, 1, 1) for x in (c, sn)]
    d = dn.to(torch.float64)
    re, im = (d * c).sum(1, keepdim=True), -(d * sn).sum(1, keepdim=True)
    return re, im, c, sn, (re == 0) & (im == 0)


def decode_flat_safe(dn: torch.Tensor, f: float):
    """Eq. (1) like :func:`~tof_fpn_torch.sim.depth_from_samples` (depth, amplitude, offset),
    with a finite gradient where the samples are all equal (amplitude 0, depth 0)."""
    re, im, _, _, flat = _phasor(dn)
    re_s = torch.where(flat, torch.ones_like(re), re)  # the 0 / 0 branch never differentiated
    phase = torch.remainder(torch.atan2(im, re_s), 2 * math.pi)
    amp = torch.where(flat, torch.zeros_like(re), torch.hypot(re_s, im) * (2.0 / dn.shape[1]))
    depth = phase * (K.SPEED_OF_LIGHT_AIR / (4 * math.pi * f))
    return depth, amp, dn.to(torch.float64).mean(1, keepdim=True)


def clipped_noise(dn: torch.Tensor, var: torch.Tensor):
    """Noise of ``(2/N) X_1`` across and along the phasor (each (H, W), DN) for samples ``dn``
    (1, N, H, W) with unequal variances ``var`` (DN^2): the delta method through eq. (1). Equal
    variances ``v`` give ``sqrt(2 v / N)`` for both; a flat pixel (no phasor) gets the mean."""
    n = dn.shape[1]
    re, im, c, sn, flat = _phasor(dn)
    var = var.to(torch.float64)
    mag = torch.sqrt(torch.where(flat, torch.ones_like(re), re * re + im * im))
    # d phase / d R_n = -(Re sin + Im cos) / |X|^2, d |X| / d R_n = (Re cos - Im sin) / |X|
    perp = (var * ((re * sn + im * c) / mag) ** 2).sum(1)[0]
    par = (var * ((re * c - im * sn) / mag) ** 2).sum(1)[0]
    iso = 0.5 * var.sum(1)[0]
    perp, par = torch.where(flat[0, 0], iso, perp), torch.where(flat[0, 0], iso, par)
    return torch.sqrt(perp) * (2.0 / n), torch.sqrt(par) * (2.0 / n)
