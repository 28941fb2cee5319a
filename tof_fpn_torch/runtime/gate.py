r"""Stripe gate: open the FPN notch stage only for frames whose stripes are really there.

A notch filter removes everything at its frequencies: fixed-pattern stripes, but also scene detail
(edges, thin objects, slopes, texture) and noise. On a frame without stripes it can only hurt (up
to 10 dB PSNR on the detailed synthetic scenes). Stripes differ from the scene in two ways one
frame shows: they are the same in every row (column stripes), and they are *narrowband*: a sharp
line at the notch frequency ``w0``, where edges, slopes and noise have a smooth spectrum.

Statistic, per image, orientation and notch (torch only, exportable: sums, no sort):

1. The column profile ``p(x)``: the mean of the depth down each column over the pixels that are
   valid and not outliers of the notch residual less its column means, ``e - mean_col e``
   (``e = x - H x``; ``|.| <= 3 s``, ``s`` a robust scale of it: object edges and thin
   high-contrast structure drop out). The column means are taken out first because the stripes
   are in ``e``: outliers judged with them would drop pixels in step with the stripe's phase and
   modulate the scene into a false line at ``w0`` (3.5 dB lost on a 1024 x 1280 scene).
2. Its Hann-windowed DFT power at ``w0`` and at the ``R`` (:data:`REFERENCES`, 8) nearest
   reference frequencies 3 to 12 bins away inside ``(0, pi)`` and 2.5 bins or more from every notch
   (another stripe line), evaluated exactly (no FFT bins: any width works).
3. ``T = P(w0) / mean P(ref)``. Without a line at ``w0`` (any smooth local spectrum) ``T`` follows
   ``F(2, 2R)``, ``P(T > t) = (1 + t / R)^-R``; the gate opens above the threshold of false-alarm
   probability ``a`` (:data:`FALSE_ALARM`, 1e-3 per notch and image), fully at twice it.
4. A floor in depth units: the line's amplitude ``a_hat`` must be at least ``min_stripe``
   (:data:`~tof_fpn_torch.constants.GATE_MIN_STRIPE`) times the per-pixel
   noise ``s / sqrt(g_e)`` (``g_e = ||delta - h||^2``), fully at twice that.

``a_hat`` is what both of two estimates allow (the smaller): the profile's ``P(w0) - mean
P(ref)``, and the line that the profiles of :data:`LINE_BANDS` (8) bands of rows share, the median
over the bands of the real and of the imaginary part of their DFTs at ``w0`` (its power less the
noise a median of the bands leaves). A stripe is the same in every band; a grating, a Siemens star
or thin bars of the scene at the notch frequency fill only some of them and counted as stripe
power in the profile of the whole frame (up to 2.8x too high).

``g`` is per image, in ``[0, 1]``, the largest over notches and orientations; both ramps are
linear, so the stage output ``x + g (stage(x) - x)`` is a continuous function of the input.

**Worth it?** (:func:`risk_shrinkage`). A detected stripe is not yet a reason to filter: on a
frame with little noise and much scene detail the notch costs the scene more than the stripes
cost (a striped planar scene at ``k = 0.3``: -1.9 to -3.4 dB with the line test alone). The
stage output ``y = x + g D`` (``D`` the ungated change: notch, then fusion with weight ``w_p``)
changes the mean squared error against the truth ``t`` by (Stein's unbiased risk estimate for a
linear smoother, with the stripes ``s`` as an error the smoother removes; derivation in
docs/runtime.md)::

    dMSE(g) = g^2 C - g B,   C = sum_p D_p^2,
    B = 2 (1 - h_0) sum_p w_p sigma_p^2 + 2 P_s sum_p w_p

``h_0`` the filter's centre tap (its product over the filtered dimensions), ``sigma_p^2`` the
per-pixel noise, ``P_s`` the stripe power per pixel (from the line amplitudes above). ``dMSE`` is
negative for every ``0 < g < B / C`` (smallest at ``B / (2 C)``). The gate is capped at
``clamp((B / C - f) / (1 - f), 0, 1)`` (``f`` = :data:`RISK_FLOOR`, 0.5): closed where the estimate says the full change costs at least twice what it gains, fully
open where it gains more than it costs, and in between below ``B / C``, where the estimated risk
falls. It is a veto, not a guarantee: the stripe power from one frame still includes scene
content at the notch frequency that fills every band of rows, and misses the stripes' amplitude
dependence (0.55x on the paper's eq. (10) data); a stricter cap (full open
only from ``B >= 2 C``) cost the paper's own demo 2.8 dB (docs/runtime.md). The noise
power ``sigma_p^2`` comes from the finest diagonal wavelet coefficients ``d`` (2 x 2
``(x00 - x01 - x10 + x11) / 2``: zero for row and column stripes, planes and ramps): with an
amplitude, the ToF law ``sigma_p = k / A_p`` with ``k`` the robust scale of ``d A``; without, the
robust scale of ``d``; either capped by the local mean of ``d^2`` (3 x 3), which bounds it where
the amplitude is near 0 and where scene detail is mistaken for noise.
"""

from __future__ import annotations

import math

import torch

from .. import constants as K
from .fpn_filter import _tracing
from .noise import clipped_scale

__all__ = [
    "FALSE_ALARM",
    "LINE_BANDS",
    "NOISE_WINDOW",
    "REFERENCES",
    "RISK_FLOOR",
    "false_alarm_threshold",
    "line_gate",
    "noise_power",
    "risk_shrinkage",
    "stripe_gate",
]

# The gate's settings (beyond the paper). TorchScript reads no module-level number inside a
# function, so they enter the functions as parameter defaults.
#: False-alarm probability of the line test, per notch frequency and image.
FALSE_ALARM: float = 1e-3
#: Reference frequencies the line test compares the notch frequency's power with.
REFERENCES: int = 8
#: Side of the window (pixels) of the local mean of the squared finest diagonal wavelet
#: coefficients that caps the per-pixel noise power (:func:`noise_power`).
NOISE_WINDOW: int = 3
#: The bands of lines (rows for column stripes) whose profiles must share a line for its power
#: to count: :func:`line_gate` takes the median over the bands (at least 4 lines each).
LINE_BANDS: int = 8
#: The gate closes where the stage's estimated benefit is at most this share of its estimated cost
#: (and opens fully where the benefit exceeds the cost): :func:`risk_shrinkage`.
RISK_FLOOR: float = 0.5


def false_alarm_threshold(references: int, probability: float = FALSE_ALARM) -> float:
    """``t`` with ``P(F(2, 2R) > t) = (1 + t / R)^-R = probability`` for ``R`` references."""
    r = float(references)
    return r * (probability ** (-1.0 / r) - 1.0)


def _line_dft(
    p: torch.Tensor, w0: float, notches: list[float], references: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Hann-windowed DFT of profiles ``p`` (B, L) at ``w0`` (column 0) and at the ``R`` reference
    frequencies nearest to it (3 to 12 bins away, inside ``(0, pi)``, at least 2.5 bins from every
    notch, where another stripe line may sit): ``(real (B, 1 + R), imaginary (B, 1 + R), sum of
    the window)``. Tensor arithmetic only, so it traces with a symbolic ``L``."""
    n = torch.arange(p.shape[1], dtype=p.dtype, device=p.device)
    length = n.numel() + torch.zeros((), dtype=p.dtype, device=p.device)
    win = 0.5 - 0.5 * torch.cos(2.0 * math.pi * (n + 1.0) / (length + 1.0))
    step = 2.0 * math.pi / length
    k = torch.arange(3, 13, dtype=p.dtype, device=p.device)
    offsets = torch.cat([-k, k])
    cand = w0 + offsets * step
    bad = (cand <= 0.0) | (cand >= math.pi)
    for w in notches:
        bad = bad | ((cand - w).abs() < 2.5 * step)
    score = offsets.abs() + 1000.0 * bad.to(p.dtype)
    ref = cand[torch.topk(score, references, largest=False).indices]
    omega = torch.cat([torch.full((1,), w0, dtype=p.dtype, device=p.device), ref])
    phase = n.unsqueeze(1) * omega.unsqueeze(0)  # (L, F)
    xw = p * win
    return xw.matmul(torch.cos(phase)), xw.matmul(torch.sin(phase)), 0.5 * (length + 1.0)


def _line_power(
    p: torch.Tensor, w0: float, notches: list[float], references: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_line_dft`'s power: ``(P0 (B,), mean P_ref (B,), sum of the window)``."""
    re, im, wsum = _line_dft(p, w0, notches, references)
    power = re * re + im * im  # (B, F)
    # (a sum, not .mean: ONNX ReduceMean changed in opset 18 and does not convert down to 17)
    return power[:, 0], power[:, 1:].sum(1) / float(references), wsum


def _profile(xk: torch.Tensor, k: torch.Tensor, avg_dim: int) -> torch.Tensor:
    """(B, L) the mean of ``xk`` along ``avg_dim`` over the pixels ``k``, less its mean over the
    lines that have any (0 on the others)."""
    n = k.sum(avg_dim).to(xk.dtype).flatten(1)  # (B, L)
    p = xk.sum(avg_dim).flatten(1) / n.clamp_min(1.0)
    has = n > 0
    mean = (p * has).sum(1, keepdim=True) / has.sum(1, keepdim=True).clamp_min(1)
    return torch.where(has, p - mean, torch.zeros_like(p))


def _median(v: torch.Tensor) -> torch.Tensor:
    """(B,) median over the last axis of ``v`` (B, n) (the mean of the two middle values for an
    even ``n``), by ranks from comparisons: no sort, so it exports."""
    n = v.shape[1]
    a, b = v.unsqueeze(2), v.unsqueeze(1)  # [., i, j]: v_i, v_j
    before = torch.ones(n, n, device=v.device).tril(-1).to(torch.bool)  # i > j
    # rank of v_i: the values below it, and the equal ones at a lower index (ranks are unique)
    rank = ((b < a) | ((b == a) & before)).sum(2)
    lo = (v * (rank == (n - 1) // 2).to(v.dtype)).sum(1)
    hi = (v * (rank == n // 2).to(v.dtype)).sum(1)
    return 0.5 * (lo + hi)


def _common_line(
    parts: torch.Tensor, w0: float, notches: list[float], references: int
) -> torch.Tensor:
    """(B,) the magnitude of the line at ``w0`` that the bands' profiles ``parts`` (B, n, L)
    share, in units of the window's sum: the median over the bands of the real and of the
    imaginary part of their windowed DFTs, its power less the noise the median leaves in it
    (``(pi / 2) / n`` of the bands' mean reference power: the variance of a median of ``n``)."""
    b, n = parts.shape[0], parts.shape[1]
    re, im, _ = _line_dft(parts.flatten(0, 1), w0, notches, references)
    f = re.shape[1]
    re, im = re.view(b, n, f), im.view(b, n, f)
    ref = (re[:, :, 1:] * re[:, :, 1:] + im[:, :, 1:] * im[:, :, 1:]).sum(2) / float(references)
    c_re, c_im = _median(re[:, :, 0]), _median(im[:, :, 0])
    noise = 0.5 * math.pi / float(n) * ref.sum(1) / float(n)
    return (c_re * c_re + c_im * c_im - noise).clamp_min(0.0).sqrt()


def stripe_gate(
    x: torch.Tensor,
    filtered: torch.Tensor,
    valid: torch.Tensor | None,
    dims: list[int],
    notches: list[float],
    gain: float,
    min_stripe: float = K.GATE_MIN_STRIPE,
) -> torch.Tensor:
    """Per-image gate in ``[0, 1]`` (shape (B, 1, 1, 1)) for a notch filter.

    Args:
        x: (B, 1, H, W) depth (invalid pixels are masked out).
        filtered: (B, 1, H, W) the filter's output ``H x``.
        valid: (B, 1, H, W) bool or None (all valid).
        dims: the filtering dimensions (-1: column stripes, -2: row stripes).
        notches: the notch frequencies (radians per sample) to test.
        gain: ``||delta - h||^2`` of the taps (white-noise power gain of ``I - H``).
        min_stripe: smallest stripe amplitude, in units of the per-pixel noise, that opens the
            gate (fully at twice that).

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> x = 2.0 + 0.01 * torch.randn(1, 1, 64, 96, generator=g)
        >>> flat = torch.full_like(x, 2.0)  # a "filter" that removed only noise
        >>> float(stripe_gate(x, flat, None, [-1], [math.pi], 1.0))
        0.0
        >>> striped = x + 0.02 * torch.cos(math.pi * torch.arange(96.0))
        >>> float(stripe_gate(striped, flat, None, [-1], [math.pi], 1.0))
        1.0
    """
    return line_gate(x, filtered, valid, dims, notches, gain, min_stripe)[0]


def line_gate(
    x: torch.Tensor,
    filtered: torch.Tensor,
    valid: torch.Tensor | None,
    dims: list[int],
    notches: list[float],
    gain: float,
    min_stripe: float = K.GATE_MIN_STRIPE,
    references: int = REFERENCES,
    bands: int = LINE_BANDS,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`stripe_gate` and the stripe power per pixel its line amplitudes imply (the sum over
    notches and orientations of ``a^2`` at ``pi``, ``a^2 / 2`` below), both (B, 1, 1, 1)."""
    if x.dtype == torch.float16 or x.dtype == torch.bfloat16:  # power sums overflow in 16 bits
        x, filtered = x.float(), filtered.float()
    e = x - filtered
    keep = torch.isfinite(e) if valid is None else valid & torch.isfinite(e)
    e = torch.where(keep, e, torch.zeros_like(e))
    t_a = false_alarm_threshold(references)
    gate = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
    power = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
    for d in dims:
        avg_dim = -2 if d == -1 else -1  # column stripes: average down the columns
        # the outliers from the residual less its line means: a stripe is constant along its
        # lines, so which pixels drop out does not follow the stripe's phase (a mask that did
        # would modulate the scene into a false line at the notch frequency)
        m = keep.sum(avg_dim, keepdim=True).to(x.dtype).clamp_min(1.0)
        ec = torch.where(keep, e - e.sum(avg_dim, keepdim=True) / m, torch.zeros_like(e))
        s = clipped_scale(ec, keep, [-3, -2, -1]).clamp_min(1e-30)
        k = keep & (ec.abs() <= 3.0 * s)
        xk = torch.where(k, x, torch.zeros_like(x))
        noise = (s / math.sqrt(max(gain, 1e-12))).flatten()
        p = _profile(xk, k, avg_dim)
        # the profiles of bands of lines (top to bottom for column stripes): a stripe is the same
        # in every band, scene content at the notch frequency (a grating, a star, thin bars)
        # is not
        size = x.shape[avg_dim]
        nb = min(bands, size // 4)
        parts: list[torch.Tensor] = []
        for b in range(nb if nb >= 2 else 0):
            lo, hi = b * size // nb, (b + 1) * size // nb
            parts.append(
                _profile(xk.narrow(avg_dim, lo, hi - lo), k.narrow(avg_dim, lo, hi - lo), avg_dim)
            )
        bands_p = torch.stack(parts, 1) if len(parts) >= 2 else p.unsqueeze(1)  # (B, nb, L)
        for w0 in notches:
            p0, ref, wsum = _line_power(p, w0, notches, references)
            t = p0 / ref.clamp_min(1e-30)
            scale = 1.0 if abs(w0 - math.pi) < 1e-9 else 0.5  # a cos at w0 < pi: half in w0
            amp = (p0 - ref).clamp_min(0.0).sqrt() / (scale * wsum)
            if len(parts) >= 2:
                line = _common_line(bands_p, w0, notches, references)
                amp = torch.minimum(amp, line / (scale * wsum))
            power = power + amp * amp * (1.0 if scale == 1.0 else 0.5)  # per pixel
            g = ((t - t_a) / t_a).clamp(0.0, 1.0)
            if min_stripe > 0:
                ratio = amp / noise
                g = g * ((ratio - min_stripe) / min_stripe).clamp(0.0, 1.0)
            gate = torch.maximum(gate, g)
    return gate.view(-1, 1, 1, 1), power.view(-1, 1, 1, 1)


def _box_sum(x: torch.Tensor, r: int) -> torch.Tensor:
    """Sum of ``x`` (..., H, W) over the (2r + 1) x (2r + 1) window around each element, zero
    outside the frame (shifted adds: exact in the order of the window's offsets)."""
    out = x
    for dim in [-1, -2]:
        n = out.shape[dim]
        acc = out.clone()
        for k in range(1, min(r, n - 1) + 1):
            acc.narrow(dim, k, n - k).add_(out.narrow(dim, 0, n - k))
            acc.narrow(dim, 0, n - k).add_(out.narrow(dim, k, n - k))
        out = acc
    return out


def _inside(n: int, r: int, like: torch.Tensor) -> torch.Tensor:
    """(n,) number of the 2r + 1 positions around each index that lie in ``[0, n)``."""
    i = torch.arange(n, device=like.device)
    return (torch.clamp(i, max=r) + torch.clamp(n - 1 - i, max=r) + 1).to(like.dtype)


def _box_count(x: torch.Tensor, r: int) -> torch.Tensor:
    """(H, W) number of elements of the (2r + 1)-square window around each element of ``x``
    (..., H, W) that lie inside the frame."""
    h, w = x.shape[-2], x.shape[-1]
    return _inside(h, r, x)[:, None] * _inside(w, r, x)[None, :]


def noise_power(
    x: torch.Tensor,
    amplitude: torch.Tensor | None,
    valid: torch.Tensor | None,
    window: int = NOISE_WINDOW,
) -> torch.Tensor:
    """(B, 1, H, W) per-pixel noise power ``sigma_p^2`` of depth ``x`` (see the module docstring):
    the ToF law ``(k / A_p)^2`` (or one robust level without an amplitude), capped by the local
    mean of the squared finest diagonal wavelet coefficients; 0 where no 2 x 2 block is valid.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> amp = torch.linspace(20.0, 200.0, 128).expand(1, 1, 96, 128)
        >>> x = 3.0 + torch.arange(128.0) * 0.01 + 2.0 / amp * torch.randn(1, 1, 96, 128, generator=g)
        >>> ratio = noise_power(x, amp, None) / (2.0 / amp) ** 2
        >>> 0.8 < float(ratio.median()) < 1.1
        True
    """
    B, _, H, W = x.shape
    if H < 2 or W < 2:
        return torch.zeros_like(x)
    ok = torch.isfinite(x) if valid is None else valid & torch.isfinite(x)
    # eager and every pixel usable (the common case): skip the masking
    dense = not _tracing() and bool(ok.all())
    xv = x if dense else torch.where(ok, x, torch.zeros_like(x))
    d = 0.5 * (xv[..., :-1, :-1] - xv[..., :-1, 1:] - xv[..., 1:, :-1] + xv[..., 1:, 1:])
    ok4 = ok[..., :-1, :-1] & ok[..., :-1, 1:] & ok[..., 1:, :-1] & ok[..., 1:, 1:]
    if not dense:
        d = torch.where(ok4, d, torch.zeros_like(d))
    if amplitude is not None:
        a = amplitude.to(x.dtype)
        if not dense:
            a = torch.where(ok, a, torch.zeros_like(a))
        a4 = 0.25 * (a[..., :-1, :-1] + a[..., :-1, 1:] + a[..., 1:, :-1] + a[..., 1:, 1:])
        k = clipped_scale(d * a4, ok4, [-3, -2, -1]).clamp_min(1e-30)
        law = (k / a4.clamp_min(1e-30)) ** 2
    else:
        law = (clipped_scale(d, ok4, [-3, -2, -1]).clamp_min(1e-30) ** 2).expand_as(d)
    r = window // 2
    # the local mean of d^2 over the window's usable blocks (inside the frame: borders average
    # fewer), as shifted sums along each axis (a 3 x 3 avg_pool2d costs several times as much)
    local = _box_sum(d * d, r)
    if dense:
        local = local / _box_count(local, r)
    else:
        local = local / _box_sum(ok4.to(x.dtype), r).clamp_min(1e-30)
    var = torch.minimum(law, local)
    if not dense:
        var = torch.where(ok4, var, torch.zeros_like(d))
    var = torch.cat([var, var[..., -1:, :]], -2)  # back to (H, W): repeat the last row, column
    var = torch.cat([var, var[..., -1:]], -1)  # (no replicate Pad: ONNX opset 17 lacks it)
    return var if dense else torch.where(ok, var, torch.zeros_like(var))


def risk_shrinkage(
    change: torch.Tensor,
    weight: torch.Tensor,
    noise: torch.Tensor,
    stripe_power: torch.Tensor,
    centre: float,
    valid: torch.Tensor | None,
    floor: float = RISK_FLOOR,
) -> torch.Tensor:
    """(B, 1, 1, 1) cap ``clamp((B / C - floor) / (1 - floor), 0, 1)`` on the gate (module
    docstring: the estimated risk change of the gated output ``x + g change`` is ``g^2 C - g B``;
    closed while ``B <= floor C``, open from ``B >= C``, and never above ``B / C`` in between).

    Args:
        change: (B, 1, H, W) the ungated change ``D`` of the stage (notch, then fusion).
        weight: (B, 1, H, W) the fusion's weight ``w_p`` of the notch output (1 without fusion).
        noise: (B, 1, H, W) per-pixel noise power (:func:`noise_power`).
        stripe_power: (B, 1, 1, 1) stripe power per pixel (:func:`line_gate`).
        centre: the filter's centre tap (its product over the filtered dimensions).
        valid: (B, 1, H, W) bool or None (all valid).
        floor: the ratio ``B / C`` at and below which the gate is closed, in ``[0, 1)``.

    Example:
        >>> D = torch.full((2, 1, 4, 4), 0.1)
        >>> w, n, ps = torch.ones_like(D), torch.full_like(D, 0.0075), torch.tensor([0.0, 1.0])
        >>> g = risk_shrinkage(D, w, n, ps.view(2, 1, 1, 1), 0.5, None)  # B / C = 0.75 and 200
        >>> [round(v, 4) for v in g.flatten().tolist()]
        [0.5, 1.0]
    """
    ok = torch.isfinite(change) if valid is None else valid & torch.isfinite(change)
    zero = torch.zeros_like(change)
    d = torch.where(ok, change, zero)
    w = torch.where(ok, weight.to(change.dtype), zero)
    cost = (d * d).sum((-3, -2, -1), keepdim=True)
    wsum = w.sum((-3, -2, -1), keepdim=True)
    gain = 2.0 * (1.0 - centre) * (w * torch.where(ok, noise, zero)).sum((-3, -2, -1), True)
    gain = gain + 2.0 * stripe_power.to(change.dtype) * wsum
    cap = ((gain / cost.clamp_min(1e-30) - floor) / (1.0 - floor)).clamp(0.0, 1.0)
    return torch.where(cost > 0, cap, torch.ones_like(cap))
