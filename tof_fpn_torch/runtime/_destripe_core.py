r"""Kernels of :func:`~tof_fpn_torch.runtime.destripe` (torch only, TorchScript-clean).

Everything here works on ``x`` of shape (N, K, H, W): N images, K = 1 (depth) or 2 (the real and
imaginary parts of ``z = A e^{j phi}``) channels that share one robust inlier test, offsets varying
along W (one per column) and constant along H. The public module turns rows into columns by a
transpose and depth into ``z`` and back. Steps (``tests/test_destripe.py`` checks them against an
independent NumPy / SciPy implementation):

1. The rows are split into a top and a bottom half; each half is estimated on its own.
2. Pilot (per half, on a strided subsample of at most ``pilot_rows / 2`` rows): the per-pair
   median of the horizontal differences ``g = x[..., 1:] - x[..., :-1]``; the robust scale
   ``sigma`` of ``|g - pilot|`` (MAD start, then clipped-RMS iterations de-biased for the clipping,
   so depth quantised to whole millimetres, where the MAD can be 0, is measured right); the pilot
   is then the trimmed mean (``|g - pilot| <= clip sigma``) of the subsample.
3. Pair means over all rows of the half: a difference more than ``clip sigma`` from the pilot (an
   edge, a bar, a curved object, an invalid pixel) is replaced by the pilot.
4. Pair means more than ``DESTRIPE_STEP_CLIP`` robust sigmas from their median over the columns
   are edges that most rows share (a wall-to-box edge, not one of a population of stripe steps):
   replaced by the median.
5. Profile: the pair means integrated along W (``cumsum``) and high-passed: minus their local
   linear fit over ``width`` (at most W / 4) columns.
   For K = 2 (the complex domain) the profiles then lose their component along each column's
   mean phasor in proportion to the column's phase coherence (:func:`coherent_projection`).
6. Shrinkage: the profile of all rows ``p`` (row-weighted mean of the halves' profiles) is split
   into octave bands (:func:`band_widths`); in each band, over all columns (``"global"``) or over
   windows of ``local_width`` columns (``"local"``), it is scaled by
   ``f = clamp((C - z sd0) / E, 0, 1)`` with ``C = <p_top, p_bottom>``, ``E = <p, p>`` and
   ``sd0`` the standard deviation of ``C`` without stripes (from ``(p_top - p_bottom)^2``).
   ``C / E`` is the positive-part James-Stein (Wiener) factor with the noise energy measured by
   cross-validation: the halves share the stripes but not their noise, nor structure confined to
   one half. Last, the offsets get zero mean over the valid pixels (the image mean never moves).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .. import constants as K
from .noise import clipped_rms_scale, mad_to_sigma, scale_moment

__all__ = ["MAX_EDGE_SHARE", "NULL_Z", "band_shrink", "column_offsets"]

# Settings of the estimator (beyond the paper; the ones the calibration shares are in
# tof_fpn_torch.constants). TorchScript reads no module-level number inside a function, so they
# enter the functions as parameter defaults.
#: A column step further than ``DESTRIPE_STEP_CLIP`` robust sigmas from the median step is a scene
#: edge that most rows share, not a stripe: dropped, unless more than this share of the columns
#: would be dropped: then they are a mode of the steps (periodic stripes such as the paper's at
#: pi make them bimodal), not rare edges (step 4).
MAX_EDGE_SHARE: float = 0.25
#: The cross-validated shrinkage keeps a profile band only as far as the energy common to the top
#: and the bottom half exceeds this many of its standard deviations without stripes (2.5: the
#: largest value that keeps >= 10 dB on the real ADI wall; stripe-free scenes then change by
#: < 0.1 dB, docs/destripe.md) (step 6).
NULL_Z: float = 2.5


def _magnitude(e: torch.Tensor) -> torch.Tensor:
    """``|e|`` over the channel dim 1 (kept), for K = 1 or 2."""
    if e.shape[1] == 1:
        return e.abs()
    return torch.sqrt((e * e).sum(1, keepdim=True))


def _inliers(g: torch.Tensor, centre: torch.Tensor, limit: torch.Tensor) -> torch.Tensor:
    """(N, 1, R, C) bool: ``|g - centre| <= limit`` over the K channels of (N, K, R, C) ``g``;
    NaN never passes."""
    if g.shape[1] == 1:
        return (g >= centre - limit) & (g <= centre + limit)
    e = g - centre
    return (e * e).sum(1, keepdim=True) <= limit * limit


def _trimmed_means(
    g: torch.Tensor, ok: torch.Tensor | None, centre: torch.Tensor, limit: torch.Tensor
) -> torch.Tensor:
    """Means (N, K, 1, C) over the rows of the inliers of ``g`` (``centre`` where there is none)."""
    inl = _inliers(g, centre, limit)
    if ok is not None:
        inl = inl & ok
    s = torch.where(inl, g, 0.0).sum(2, keepdim=True)
    n = inl.sum(2, keepdim=True).to(g.dtype)
    return torch.where(n > 0, s / n.clamp_min(1.0), centre)


def _pilot(
    x: torch.Tensor, valid: torch.Tensor | None, clip: float, moment: float, rows: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per half: ``(pilot pair means (2N, K, 1, W - 1), sigma (2N,))``, top halves first, from a
    strided subsample of both halves of (N, K, H, W) ``x`` (the same step in both; at most
    ``rows`` rows, equally many from each): per-pair median, robust scale around it, trimmed
    mean."""
    k, h = x.shape[1], x.shape[2]
    half = h // 2
    step = max(1, (h - half + rows - 1) // rows)
    count = min((half + step - 1) // step, (h - half + step - 1) // step)
    top = torch.arange(count, device=x.device) * step
    idx = torch.cat([top, top + half])
    xs = x.index_select(2, idx)
    xs = torch.cat([xs[:, :, :count], xs[:, :, count:]], 0)  # (2N, K, count, W)
    gs = xs[..., 1:] - xs[..., :-1]
    oks: torch.Tensor | None = None
    if valid is not None:
        vs = valid.index_select(2, idx)
        vs = torch.cat([vs[:, :, :count], vs[:, :, count:]], 0)
        oks = vs[..., 1:] & vs[..., :-1]
        gt = torch.where(oks, gs, math.nan).transpose(2, 3).contiguous()
        pilot = torch.nan_to_num(torch.nanmedian(gt, dim=3).values, nan=0.0)[:, :, None]
    else:  # torch's median is the lower middle value: the ((n + 1) // 2)-th smallest
        kth = (gs.shape[2] + 1) // 2
        pilot = gs.transpose(2, 3).contiguous().kthvalue(kth, dim=3).values[:, :, None]
    sigma = clipped_rms_scale(_magnitude(gs - pilot), oks, clip, moment, k)
    pilot = _trimmed_means(gs, oks, pilot, clip * sigma[:, None, None, None])
    return pilot, sigma


def _half_means(
    x: torch.Tensor, valid: torch.Tensor | None, pilot: torch.Tensor, limit: torch.Tensor
) -> torch.Tensor:
    """Robust means (N, K, W - 1) of the pair differences over the rows of ``x`` (N, K, R, W).

    A difference further than ``limit`` (N, 1, 1, 1) from ``pilot`` (N, K, 1, W - 1), or invalid,
    is replaced by the pilot and the mean is taken over all ``R`` rows: one select and one sum, no
    counts (the fixed point of this imputation is the trimmed mean; one step from the pilot differs
    from it by ``outlier share * (pilot - trimmed mean)``). These few passes are the stage's cost."""
    if valid is None and x.shape[1] == 1:
        # sum of where(|g - pilot| <= limit, g, pilot) = sum g - limit * sum hardshrink(t, 1) with
        # t = (g - pilot) / limit, and sum g from the column sums of x: no masks, no counts
        inv = 1.0 / limit.clamp_min(1e-30)
        t = torch.addcmul(-pilot * inv, x[..., :-1], -inv)
        t.addcmul_(x[..., 1:], inv)
        cs = x.sum(2)
        s = (cs[..., 1:] - cs[..., :-1]) - limit[:, :, 0] * F.hardshrink(t, 1.0).sum(2)
        s = torch.where(limit[:, :, 0] > 0, s, pilot[:, :, 0] * x.shape[2])
    else:
        g = x[..., 1:] - x[..., :-1]
        inl = _inliers(g, pilot, limit)
        if valid is not None:
            inl = inl & (valid[..., 1:] & valid[..., :-1])
        s = torch.where(inl, g, pilot).sum(2)
    return s.double() / max(1, x.shape[2])


def _reject_steps(
    m: torch.Tensor, clip: float, max_edge_share: float = MAX_EDGE_SHARE
) -> torch.Tensor:
    """Pair means (N, K, C) whose distance from their median over the columns exceeds ``clip``
    robust sigmas (MAD) of that distance are scene edges that most rows share (a stripe step is
    one of a population of similar steps; a wall-to-box edge is rare): they are replaced by the
    median. Unless they are more than ``max_edge_share`` (:data:`MAX_EDGE_SHARE`) of the columns: then they are a
    mode of the steps, not edges (a periodic pattern such as the paper's stripes at pi makes the
    steps bimodal, and the median sits on one mode), and nothing is rejected. Medians are
    mid-point ones (``quantile(0.5)``); a zero scale rejects nothing."""
    med = torch.quantile(m, 0.5, dim=-1, keepdim=True)
    mag = _magnitude(m - med)
    typical = torch.quantile(mag, 0.5, dim=-1, keepdim=True)
    sigma = mad_to_sigma(typical, m.shape[1])
    edge = (mag > clip * sigma) & (sigma > 0)
    rare = edge.to(m.dtype).mean(-1, keepdim=True) <= max_edge_share
    return torch.where(edge & rare, med, m)


def _window_sums(p: torch.Tensor, width: int) -> list[torch.Tensor]:
    """Window sums over ``[x - h, x + h]`` (clipped to the line) of ``1, j, j^2, p, j p`` along the
    last dim of (N, K, W) float64 ``p`` (``h = width // 2``)."""
    w = p.shape[-1]
    h = width // 2
    j = torch.arange(w, dtype=p.dtype, device=p.device)
    hi = torch.clamp(torch.arange(w, device=p.device) + h + 1, max=w)
    lo = torch.clamp(torch.arange(w, device=p.device) - h, min=0)
    out: list[torch.Tensor] = []
    for q in (torch.ones_like(j), j, j * j):
        c = F.pad(q.cumsum(0), (1, 0))
        out.append(c[hi] - c[lo])
    for q in (p, p * j):
        c = F.pad(q.cumsum(-1), (1, 0))
        out.append(c.index_select(-1, hi) - c.index_select(-1, lo))
    return out


def highpass(p: torch.Tensor, width: int) -> torch.Tensor:
    """``p`` minus its local linear least-squares fit over ``width`` samples (windows clipped at
    the ends, so a linear trend is removed exactly everywhere), along the last dim, float64."""
    s0, sj, sjj, sp, sjp = _window_sums(p, width)
    mj = sj / s0
    vjj = sjj / s0 - mj * mj
    mp = sp / s0
    cov = sjp / s0 - mj * mp
    slope = torch.where(vjj > 1e-9, cov / vjj.clamp_min(1e-9), torch.zeros_like(cov))
    j = torch.arange(p.shape[-1], dtype=p.dtype, device=p.device)
    return p - (mp + slope * (j - mj))


def _box_sum(p: torch.Tensor, width: int) -> torch.Tensor:
    w = p.shape[-1]
    h = width // 2
    hi = torch.clamp(torch.arange(w, device=p.device) + h + 1, max=w)
    lo = torch.clamp(torch.arange(w, device=p.device) - h, min=0)
    c = F.pad(p.cumsum(-1), (1, 0))
    return c.index_select(-1, hi) - c.index_select(-1, lo)


def _profile(pair: torch.Tensor, width: int) -> torch.Tensor:
    """Integrated, high-passed column profile (N, K, W) from pair means (N, K, W - 1)."""
    return highpass(F.pad(pair.cumsum(-1), (1, 0)), width)


def column_offsets(
    x: torch.Tensor,
    valid: torch.Tensor | None,
    width: int,
    clip: float,
    shrink: str,
    local_width: int,
    pilot_rows: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Column offsets of (N, K, H, W) ``x`` (module docstring): ``(offsets (N, K, W), factor)``
    with ``factor`` the shrinkage applied, (N, 1, 1) or (N, 1, W) for ``"local"``. ``valid`` is
    (N, 1, H, W) bool or None (all valid); invalid entries of ``x`` are never read as data."""
    k, h = x.shape[1], x.shape[2]
    moment = scale_moment(k, clip)
    half = h // 2
    # each half has its own pilot: the halves must not share anything but the stripes (a shared
    # pilot, imputed at both halves' outliers, made structured scenes look striped)
    n = x.shape[0]
    pilot, sigma = _pilot(x, valid, clip, moment, max(1, pilot_rows // 2))
    limit = clip * sigma[:, None, None, None].to(x.dtype)
    v_top = None if valid is None else valid[:, :, :half]
    v_bot = None if valid is None else valid[:, :, half:]
    m_top = _half_means(x[:, :, :half], v_top, pilot[:n], limit[:n])
    m_bot = _half_means(x[:, :, half:], v_bot, pilot[n:], limit[n:])
    m = _reject_steps(torch.cat([m_top, m_bot], 0), K.DESTRIPE_STEP_CLIP)
    # a smooth scene profile common to both halves passes the cross-validation: the high-pass
    # must be short against the line, so at most a quarter of it
    width = max(3, min(width, x.shape[-1] // 4))
    p = _profile(m, width)
    if k == 2:  # before the shrinkage: what is dropped must not count as stripes
        p = coherent_projection(p, x.sum(2).repeat(2, 1, 1), _abs_sum(x).repeat(2, 1, 1))
    p_top, p_bot = p[:n], p[n:]
    p_all = (half * p_top + (h - half) * p_bot) / h
    count = torch.ones_like(p_all[:, :1]) if valid is None else valid.sum(2, dtype=torch.float64)
    if shrink == "none":
        return _zero_mean(p_all, count).to(x.dtype), torch.ones_like(p_all[:, :1, :1]).to(x.dtype)
    out, factors = band_shrink(p_top, p_bot, p_all, width, shrink == "local", local_width)
    return _zero_mean(out, count).to(x.dtype), factors.to(x.dtype)


def band_shrink(
    p_top: torch.Tensor,
    p_bot: torch.Tensor,
    p_all: torch.Tensor,
    width: int,
    local: bool,
    local_width: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Step 7 of the module docstring: ``p_all`` (N, K, W) split into octave bands (high-pass
    widths :func:`band_widths` of ``width``), each band scaled by the cross-validated factor of the
    same band of the independent estimates ``p_top`` and ``p_bot`` (per window of ``local_width``
    when ``local``): ``(sum of the scaled bands, factors (bands, N, 1, W or 1))``."""
    n = p_all.shape[0]
    out = torch.zeros_like(p_all)
    factors: list[torch.Tensor] = []
    # octave bands of the three profiles at once: coarsest = p - HP_w0, ..., finest = HP_wlast
    stack = torch.cat([p_top, p_bot, p_all], 0)
    upper = stack
    widths = band_widths(width)
    for i in range(len(widths) + 1):
        lower = highpass(stack, widths[i]) if i < len(widths) else torch.zeros_like(stack)
        band = upper - lower
        a, b, c = band[:n], band[n : 2 * n], band[2 * n :]
        f = _factor(a, b, c, local, local_width)
        factors.append(f)
        out = out + f * c
        upper = lower
    return out, torch.stack(factors, 0)


def _abs_sum(z: torch.Tensor) -> torch.Tensor:
    """``sum_y |z|`` (N, 1, W) of (N, 2, H, W) ``z`` (invalid pixels are 0)."""
    return torch.sqrt((z * z).sum(1, keepdim=True)).sum(2)


def coherent_projection(p: torch.Tensor, s: torch.Tensor, total: torch.Tensor) -> torch.Tensor:
    """Complex column profiles ``p`` (N, 2, W) with their component along each column's mean
    phasor ``u = s / |s|`` (``s = sum_y z``) scaled by ``1 - kappa^2``, ``kappa = |s| / total``
    (``total = sum_y |z|``) the column's phase coherence.

    Along ``u`` an offset changes only the amplitude of the pixels at the column's phase, not their
    depth; and a vertical amplitude texture of the scene (a painted wall), which the estimator
    cannot tell from a column offset, lies exactly there. In a column of one phase (``kappa = 1``)
    that component is dropped; in a column of many phases it is kept, since it moves the depth of
    the pixels at the other phases. Applied before the shrinkage, so the texture does not count as
    stripes there either. Measured in docs/destripe.md."""
    norm = torch.sqrt((s * s).sum(1, keepdim=True))
    u = torch.where(norm > 0, s / norm.clamp_min(1e-30), 0.0)
    kappa = torch.where(total > 0, norm / total.clamp_min(1e-30), 0.0)
    return p - (kappa * kappa) * (p * u).sum(1, keepdim=True) * u


def band_widths(width: int) -> list[int]:
    """High-pass widths splitting the profile into octave bands: ``width // 2``, ``width // 4``,
    ... down to 5 columns (none below 5)."""
    out: list[int] = []
    w = width // 2
    while w >= 5:
        out.append(w)
        w = w // 2
    return out


def _factor(
    top: torch.Tensor,
    bot: torch.Tensor,
    full: torch.Tensor,
    local: bool,
    window: int,
    null_z: float = NULL_Z,
) -> torch.Tensor:
    """Cross-validated positive-part factor ``clamp((C - z sd0(C)) / E, 0, 1)`` with ``C`` the
    cross energy of the two halves, ``E`` the energy of ``full`` and ``sd0(C)`` the standard
    deviation of ``C`` without stripes, estimated from the halves' difference: per column the noise
    variance of each half is about ``(top - bottom)^2 / 2``."""
    cross = (top * bot).sum(1, keepdim=True)
    energy = (full * full).sum(1, keepdim=True)
    # without stripes var(top * bottom) = v_t v_b, and E[(d^2 / 2)^2] = 3 v^2 for Gaussian d
    d2 = ((top - bot) * (top - bot)).sum(1, keepdim=True) * 0.5
    null = d2 * d2 * (1.0 / 3.0)
    if local:
        cross, energy, null = (_box_sum(t, window) for t in (cross, energy, null))
    else:
        cross, energy, null = (t.sum(-1, keepdim=True) for t in (cross, energy, null))
    signal = cross - null_z * torch.sqrt(null)
    return torch.where(energy > 0, signal / energy.clamp_min(1e-300), 0.0).clamp(0.0, 1.0)


def _zero_mean(p: torch.Tensor, count: torch.Tensor) -> torch.Tensor:
    """``p`` minus its mean weighted by the valid pixels per column ``count`` (N, 1, W): the image
    mean does not move."""
    return p - (p * count).sum(-1, keepdim=True) / count.sum(-1, keepdim=True).clamp_min(1.0)
