"""Negative log-likelihood of a recording under a model, frames pooled (depth and amplitude domain).

For a Gaussian model with per-pixel mean ``mu`` and per-frame sd ``sigma`` the frame-level NLL of
pixel ``p`` is computed exactly from its ``(n, m, M2)``::

    0.5 [log(2 pi v_m) + (m - mu)^2 / v_m] + 0.5 [(n - 1) log(2 pi sigma^2) + M2 / sigma^2]
    + 0.5 log n,          v_m = sigma^2 / n + tau^2

(``tau``: a random effect fixed over time, e.g. the pixel gain on the amplitude, a fixed
per-pixel offset on the depth). Depth and
amplitude count as independent (their noises are orthogonal components of ``X_1``). Terms that
act per frame change the statistics: a per-frame change of the means (``Term.frame_means``,
``temporal_drift``) is subtracted before they are taken; an outlier rate ``r``
(``Term.outlier_rate``, ``impulsive_pixels``) turns every frame-pixel into a mixture
``(1 - r) N_D N_A + r U_D U_A`` with uniform densities over the observed depth and amplitude
ranges, evaluated on the frames themselves; a heavy-tailed depth noise (``Term.depth_tail``,
``noise_floor_tails``) makes each depth reading Student-t with ``dof`` degrees of freedom about
its mean, scaled to the predicted variance ``v`` (scale ``s^2 = v (dof - 2) / dof``): the
pooled Gaussian NLL less, frame by frame, the log-ratio of the Student-t to the Gaussian density
of each reading's deviation from its pixel's temporal mean (so that the pixel means keep their
Gaussian law and random effects, and a large ``dof`` gives the Gaussian NLL back; readings over
``CENTRE_Z`` sd from the pixel's median are left out of that mean, so that an outlier does not
move it); with the outlier mixture the same log-ratio is
added to the inlier component's log-density, so that an outlier rate going to 0 gives the NLL
without outliers back where no random effect is stated). Mixed pixels at
depth edges with a free share (``Term.edge_mixture``) turn the temporal mean of each edge pixel into a mixture over the share
(pooled statistics only: not combined with the outlier mixture).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from ..constants import SPEED_OF_LIGHT_AIR
from .data import Observations, pixel_stats
from .densities import LOG_2PI, gauss_log_density, pixel_centre, student_log_density

__all__ = [
    "CLIP_SHARE",
    "EDGE_MARGIN",
    "MIX_GRID",
    "MIN_SNR_AMPLITUDE",
    "MIN_SNR_DEPTH",
    "SPLIT_BLOCK",
    "Context",
    "make_context",
    "n_observations",
    "nll",
]

#: Pixels enter the depth likelihood where the predicted amplitude is at least this many times
#: the noise of one component of (2/N) X_1 (below it the phase is far from Gaussian) ...
MIN_SNR_DEPTH: float = 5.0
#: ... and the amplitude likelihood above this (the Rician mean and spread are used).
MIN_SNR_AMPLITUDE: float = 2.0
#: Shares ``s`` of the grid on which the edge mixture's best share is searched (twice: coarse,
#: then as fine around the best; ``Term.edge_mixture``).
MIX_GRID: int = 32
#: Edge pairs with a side whose predicted largest sample reaches this share of the clip level
#: are left out of the edge mixture (the light mixes before the clip).
CLIP_SHARE: float = 0.9
#: Side (px) of the blocks of the checkerboard split into fitting and held-out pixels (smaller
#: on a frame whose shorter side is under three blocks, so that both halves have pixels).
SPLIT_BLOCK: int = 8
#: With an estimated scene, pixels within this many px of a depth edge of the estimate are left
#: out of the likelihood (the smoothing cannot follow the edge there).
EDGE_MARGIN: int = 2


@dataclass
class Context:
    """Fixed for one diagnosis: the pixel masks of the two channels, the split into fitting
    (``train``) and held-out (``test``) pixels, the cached scene and the outlier densities."""

    mask_d: torch.Tensor
    mask_a: torch.Tensor
    train: torch.Tensor
    test: torch.Tensor
    scene: object
    depth_span: float
    amp_span: float
    _frames: dict = field(default_factory=dict)
    #: what a term computes once per diagnosis from the scene (by the term's own keys)
    cache: dict = field(default_factory=dict)

    def select(self, sel: str) -> torch.Tensor:
        if sel == "all":
            return torch.ones_like(self.train)
        return self.train if sel == "train" else self.test

    def frames(self, obs: Observations, sel: str, channel: str):
        """Frames of the selected pixels of a channel: (T, P) values, validity, pixel index."""
        key = (sel, channel)
        if key not in self._frames:
            m = (self.mask_d if channel == "d" else self.mask_a) & self.select(sel)
            idx = m.reshape(-1).nonzero().squeeze(1)
            t = obs.frames
            x = (obs.depth if channel == "d" else obs.amplitude).reshape(t, -1)[:, idx]
            v = obs.valid.reshape(t, -1)[:, idx]
            self._frames[key] = (torch.where(v, x, torch.zeros_like(x)), v, idx)
        return self._frames[key]


def make_context(obs: Observations, snr: torch.Tensor) -> Context:
    """Masks from the predicted SNR (``A_0 / s``), the checkerboard split, outlier ranges."""
    base = obs.known & (obs.n > 0)
    if obs.scene_estimated:  # the estimate is poor within a few px of a depth edge
        from .axes import edge_distance

        base &= edge_distance(obs.scene_depth, obs.known) > EDGE_MARGIN
    mask_d = base & (snr >= MIN_SNR_DEPTH)
    mask_a = base & (snr >= MIN_SNR_AMPLITUDE)
    h, w = obs.shape
    b = max(1, min(SPLIT_BLOCK, min(h, w) // 3))
    yy = torch.arange(h).view(h, 1) // b
    xx = torch.arange(w).view(1, w) // b
    train = ((yy + xx) % 2) == 0
    dv = obs.depth[obs.valid]
    av = obs.amplitude[obs.valid]
    span_d = max(float(dv.max()), float(obs.scene_depth[obs.known].max())) * 1.05
    span_a = max(float(av.max()), 1e-6) * 1.05
    return Context(mask_d, mask_a | mask_d, train, ~train, obs.scene(), span_d, span_a)


def n_observations(obs: Observations, ctx: Context, sel: str = "all") -> float:
    s = ctx.select(sel)
    return float(obs.n[ctx.mask_d & s].sum() + obs.n[ctx.mask_a & s].sum())


def _gauss_ss(n, m, m2, mu, sd, tau, wrap):
    r = m - mu
    if wrap is not None:
        r = r - wrap * torch.round(r / wrap)
    var = sd * sd
    vm = var / n + tau * tau if isinstance(tau, torch.Tensor) else var / n + tau**2
    out = 0.5 * (torch.log(vm) + LOG_2PI + r * r / vm)
    out = out + 0.5 * ((n - 1) * (torch.log(var) + LOG_2PI) + m2 / var) + 0.5 * torch.log(n)
    return out.sum()


def _pick(x, idx):
    if isinstance(x, torch.Tensor) and x.dim() == 2:
        return x.reshape(-1)[idx]
    return x


def nll(model, obs: Observations, ctx: Context, pred, v: dict, sel: str = "all") -> torch.Tensor:
    """Frame-level NLL (nats) of the selected pixels of both channels."""
    terms = model.terms
    per_frame = [x for x in (t.frame_means(v, obs, model) for t in terms) if x is not None]
    rate = next((r for r in (t.outlier_rate(v) for t in terms) if r is not None), None)
    mixed = next((r for r in (t.edge_mixture(v) for t in terms) if r is not None), None)
    tail = next((r for r in (t.depth_tail(v) for t in terms) if r is not None), None)
    out = _nll_frames(obs, ctx, pred, sel, per_frame, rate, tail)
    if mixed is not None and rate is None and tail is None:
        clip = next((c for c in (t.clip_level(v) for t in terms) if c is not None), None)
        if clip is not None:  # it selects pixels: no graph
            clip = float(torch.as_tensor(clip).detach())
        if per_frame:  # the mixture's cost with no mixing must be the pixel's cost above
            obs, pred = _frame_adjusted(obs, pred, per_frame)
        out = out + _edge_mixture(
            obs, ctx, pred, mixed, sel, model.camera.modulation_frequency, clip
        )
    return out


def _frame_adjusted(obs: Observations, pred, per_frame: list):
    """The pixels' statistics and predictions with the per-frame means taken out as
    :func:`_nll_frames` takes them out (each frame moved to frame 0's mean), so that the edge
    mixture replaces the cost the frames counted. (With the pooled statistics instead, a drift
    that left frame 0's prediction far off made the mixture's no-mixing cost, which it
    subtracts, as large as it liked: the NLL fell without bound.)"""
    t = obs.frames
    shift = torch.zeros(t, 1, 1, dtype=torch.float64)
    factor = torch.ones(t, 1, 1, dtype=torch.float64)
    for s, f in per_frame:
        shift = shift + torch.as_tensor(s, dtype=torch.float64).reshape(-1, 1, 1)
        factor = factor * torch.as_tensor(f, dtype=torch.float64).reshape(-1, 1, 1)
    depth = obs.depth - (shift - shift[:1])
    amp = obs.amplitude - pred.mu_a * (factor - factor[:1])
    n, m_d, m2_d = pixel_stats(torch.where(obs.valid, depth, torch.zeros_like(depth)), obs.valid)
    _, m_a, m2_a = pixel_stats(torch.where(obs.valid, amp, torch.zeros_like(amp)), obs.valid)
    obs = replace(obs, n=n, m_d=m_d, m2_d=m2_d, m_a=m_a, m2_a=m2_a)
    f0 = factor[0, 0, 0]
    pred = replace(pred, mu_d=pred.mu_d + shift[0, 0, 0], mu_a=pred.mu_a * f0, a0=pred.a0 * f0)
    return obs, pred


def _nll_frames(obs: Observations, ctx: Context, pred, sel: str, per_frame: list, rate, tail=None):
    """The NLL without the edge mixture: pooled, or frame by frame (per-frame means, outliers,
    a heavy-tailed depth noise)."""
    if not per_frame and rate is None and tail is None:
        return _nll_pooled(obs, ctx, pred, sel)
    xd, vd, idd = ctx.frames(obs, sel, "d")
    xa, va, ida = ctx.frames(obs, sel, "a")
    mu_d, sd_d = _pick(pred.mu_d, idd).view(1, -1), _pick(pred.sd_d, idd).view(1, -1)
    mu_a, sd_a = _pick(pred.mu_a, ida).view(1, -1), _pick(pred.sd_a, ida).view(1, -1)
    tau = _pick(pred.tau_a, ida)
    tau = tau.view(1, -1) if isinstance(tau, torch.Tensor) else tau
    for shift, factor in per_frame:
        mu_d = mu_d + shift
        mu_a = mu_a * factor
    if rate is None:
        yd = xd - (mu_d - mu_d[:1]) if per_frame else xd
        ya = xa - (mu_a - mu_a[:1]) if per_frame else xa
        n, m, m2 = pixel_stats(yd, vd)
        out = _gauss_ss(n, m, m2, mu_d[0], sd_d[0], _pick(pred.tau_d, idd), pred.wrap)
        if tail is not None:
            out = out - _tail_gain(yd, vd, sd_d[0], tail, pred.wrap)
        n, m, m2 = pixel_stats(ya, va)
        tau0 = tau[0] if isinstance(tau, torch.Tensor) else tau
        return out + _gauss_ss(n, m, m2, mu_a[0], sd_a[0], tau0, None)
    depth, amp = (xd, vd, idd, mu_d, sd_d), (xa, va, ida, mu_a, sd_a)
    return _nll_mixture(ctx, pred, rate, depth, amp, tau, tail)


def _edge_mixture(obs: Observations, ctx: Context, pred, prob, sel: str, freq: float, clip=None):
    """What the NLL of the edge pixels (of both channels' masks) changes by when each is, with
    probability ``prob``, a mixture ``(1 - s) z_p + s z_q`` of its own predicted phasor and its
    partner's across the edge (``sim.edge_partners`` of the scene), ``s`` uniform in (0, 1) and
    integrated out by Laplace's approximation about its best value (the peak in ``s`` is far
    narrower than any grid: the temporal mean is precise). The mixed light's noise variance is
    the shares' mixture of the two pixels' (shot noise of the photons it collects), and its
    depth's sd grows as the phasors cancel (``|z_p| / |z(s)|``, up to that of a phase uniform
    over the range): the spread parts of the NLL change too."""
    key = ("edges", sel)
    if key not in ctx._frames:
        from ..sim import edge_partners

        part = edge_partners(obs.scene_depth.to(torch.float64)).view(-1)
        ma = ctx.mask_a.reshape(-1)
        # a partner outside the likelihood (invalid, clipped, dark) has no trusted phasor
        m = (ctx.mask_a & ctx.select(sel)).view(-1) & (part >= 0) & ma[part.clamp_min(0)]
        idx = m.nonzero().squeeze(1)
        ctx._frames[key] = (idx, part[idx], ctx.mask_d.reshape(-1)[idx].to(torch.float64))
    idx, q, has_d = ctx._frames[key]
    if clip is not None:  # the light mixes before the clip: a clipped side's phasor is not it
        peak = (pred.offset + pred.a0).detach().reshape(-1)
        ok = (peak[idx] < CLIP_SHARE * clip) & (peak[q] < CLIP_SHARE * clip)
        idx, q, has_d = idx[ok], q[ok], has_d[ok]
    if idx.numel() == 0:
        return torch.zeros((), dtype=torch.float64)
    k = 4.0 * math.pi * float(freq) / SPEED_OF_LIGHT_AIR

    def at(x, i):
        return x.reshape(-1)[i] if isinstance(x, torch.Tensor) else x

    mu_d, a_p, a_q = at(pred.mu_d, idx), at(pred.a0, idx), at(pred.a0, q)
    dphi = k * (at(pred.mu_d, q) - mu_d)
    n = at(obs.n, idx).clamp_min(1)
    sd0, tau2 = at(pred.sd_d, idx), at(pred.tau_d, idx) ** 2
    sa0, tau2_a = at(pred.sd_a, idx), at(pred.tau_a, idx) ** 2
    sp2, sq2 = at(pred.s, idx) ** 2, at(pred.s, q) ** 2
    md, ma, mu_a = at(obs.m_d, idx), at(obs.m_a, idx), at(pred.mu_a, idx)
    m2d, m2a = at(obs.m2_d, idx), at(obs.m2_a, idx)
    # the decoder folds the phase into the range: the camera's, or the shorter one the model
    # states (``pred.wrap``, phase wrapping), by which the pooled NLL folds the residual too (at
    # s = 0 this cost must be that pixel's pooled NLL: a residual folded only there made the
    # edge term lower without bound as the depth noise shrank)
    r_cam = 2 * math.pi / k
    if pred.wrap is not None:
        r_cam = pred.wrap.reshape(()) if isinstance(pred.wrap, torch.Tensor) else pred.wrap
    sd_max = r_cam / math.sqrt(12.0)  # a phase uniform over the range

    def gauss(r, var, vm, m2):  # the NLL of a pixel's mean and spread (no constants)
        return torch.log(vm) + r * r / vm + (n - 1) * torch.log(var) + m2 / var

    def cost(s):  # the NLL of both channels at shares s
        zr = (1 - s) * a_p + s * a_q * torch.cos(dphi)
        zi = s * a_q * torch.sin(dphi)
        zr = torch.where(zr.abs() < 1e-9, zr + 1e-9, zr)  # atan2 and sqrt: no 0 / 0 gradient
        mag = torch.sqrt(zr * zr + zi * zi)
        # the mixed light's noise: its photons are the two pixels' in the mixture's shares
        grow = ((1 - s) * sp2 + s * sq2) / sp2.clamp_min(1e-300)
        var_d = (sd0**2 * grow * (a_p / mag.clamp_min(1e-12)) ** 2).clamp_max(sd_max**2)
        var_a = sa0**2 * grow
        dd = md - mu_d - torch.atan2(zi, zr) / k
        dd = dd - r_cam * torch.round(dd / r_cam)  # the decoder folds the phase
        da = ma - (mu_a - a_p + mag)  # the Rician bias of the own amplitude kept
        depth = gauss(dd, var_d, var_d / n + tau2, m2d)
        # amplitude-only pixels have no depth part
        return 0.5 * (has_d * depth + gauss(da, var_a, var_a / n + tau2_a, m2a))

    l0 = cost(torch.zeros_like(mu_d))
    s_hat, width = _best_share(cost)
    p = torch.as_tensor(prob, dtype=torch.float64).clamp(1e-12, 1 - 1e-12)
    # Laplace's approximation of log of the integral over s in (0, 1) of e^{-cost(s)}
    log_int = -cost(s_hat) + torch.log(width)
    # -log[(1 - p) e^{-l0} + p int e^{-cost}] in place of l0
    return (-torch.logaddexp(torch.log1p(-p) - l0, torch.log(p) + log_int) - l0).sum()


def _best_share(cost) -> tuple[torch.Tensor, torch.Tensor]:
    """The share ``s`` in [0, 1] that minimises ``cost`` per pixel (a grid of
    :data:`MIX_GRID`, then one as fine around the best; no gradient: at the minimum the
    gradient of the cost in ``s`` is zero) and the width ``min(sqrt(2 pi / cost''), 1)`` of
    the peak (Laplace; a flat cost spreads over the whole interval)."""
    with torch.no_grad():
        g = MIX_GRID
        grid = (torch.arange(g, dtype=torch.float64).view(-1, 1) + 0.5) / g
        best = grid[cost(grid).argmin(0), 0]
        fine = best.view(1, -1) + (
            torch.arange(g + 1, dtype=torch.float64).view(-1, 1) / g - 0.5
        ) * (2.0 / g)
        fine = fine.clamp(0.0, 1.0)
        s = fine.gather(0, cost(fine).argmin(0).view(1, -1)).view(-1)
        h = 1.0 / (64 * g)
        lo, hi = (s - h).clamp(0.0, 1.0), (s + h).clamp(0.0, 1.0)
        c0 = cost(s)
        curv = (
            (cost(hi) - c0) / (hi - s).clamp_min(1e-12)
            - (c0 - cost(lo)) / (s - lo).clamp_min(1e-12)
        ) / (0.5 * (hi - lo).clamp_min(1e-12))
        width = torch.sqrt(2 * math.pi / curv.clamp_min(1e-12)).clamp_max(1.0)
    return s, width


def _pooled_stats(obs: Observations, ctx: Context, sel: str) -> tuple:
    """``(depth pixels, amplitude pixels, their (n, m, M2))`` of the ``sel`` pixels: flat
    indices in row-major order (what a boolean mask selects) and the pixels' statistics, kept on
    ``ctx`` for the observations they were taken of (every objective evaluation needs them)."""
    key = ("pooled", sel)
    held = (obs.n, obs.m_d, obs.m2_d, obs.m_a, obs.m2_a)
    entry = ctx._frames.get(key)  # one read: another thread may replace the entry meanwhile
    if entry is None or any(a is not b for a, b in zip(entry[0], held, strict=True)):
        s = ctx.select(sel)
        idd = (ctx.mask_d & s).reshape(-1).nonzero().squeeze(1)
        ida = (ctx.mask_a & s).reshape(-1).nonzero().squeeze(1)
        n, m_d, m2_d, m_a, m2_a = (x.reshape(-1) for x in held)
        stats = (n[idd], m_d[idd], m2_d[idd], n[ida], m_a[ida], m2_a[ida])
        entry = (held, idd, ida, stats)
        ctx._frames[key] = entry
    return entry[1], entry[2], entry[3]


def _nll_pooled(obs: Observations, ctx: Context, pred, sel: str) -> torch.Tensor:
    """The NLL from each pixel's ``(n, m, M2)`` (no term acts per frame)."""
    idd, ida, (n_d, m_d, m2_d, n_a, m_a, m2_a) = _pooled_stats(obs, ctx, sel)
    tau_d = _pick(pred.tau_d, idd)
    out = _gauss_ss(n_d, m_d, m2_d, _pick(pred.mu_d, idd), _pick(pred.sd_d, idd), tau_d, pred.wrap)
    tau = _pick(pred.tau_a, ida)
    return out + _gauss_ss(n_a, m_a, m2_a, _pick(pred.mu_a, ida), _pick(pred.sd_a, ida), tau, None)


def _tail_gain(yd, vd, sd, tail, wrap) -> torch.Tensor:
    """The log-likelihood a Student-t law (``dof = 1 / tail``) of the readings about their
    pixel's temporal mean (:func:`~tof_fpn_torch.diagnosis.densities.pixel_centre`) adds to a Gaussian one of the same variance ``sd^2``: the pooled
    Gaussian NLL minus this is the NLL with heavy-tailed readings (a composite likelihood: the
    pixel means, with their random effects, stay Gaussian; 0 as ``dof`` grows)."""
    dev = yd - pixel_centre(yd, vd, sd.view(1, -1))
    if wrap is not None:
        dev = dev - wrap * torch.round(dev / wrap)
    var = (sd * sd).view(1, -1)
    return ((student_log_density(dev, var, tail) - gauss_log_density(dev, var)) * vd).sum()


def _depth_log_density(rd, pred, idd, sd_d, tail) -> torch.Tensor:
    """Log-density (T, P) of the depth residuals ``rd`` (folded by the stated range), Gaussian
    or, with ``tail``, Student-t, of variance ``sd_d^2 + tau_d^2``."""
    if pred.wrap is not None:
        rd = rd - pred.wrap * torch.round(rd / pred.wrap)
    tau_d = _pick(pred.tau_d, idd)
    var = sd_d**2 + (tau_d.view(1, -1) ** 2 if isinstance(tau_d, torch.Tensor) else tau_d**2)
    if tail is None:
        return gauss_log_density(rd, var)
    return student_log_density(rd, var, tail)


def _nll_mixture(ctx: Context, pred, rate, depth: tuple, amp: tuple, tau, tail=None):
    """The NLL of every frame-pixel under the mixture with outlier rate ``rate`` (None: no
    outliers) and depth noise Gaussian or, with ``tail``, Student-t; ``depth`` and ``amp``:
    frames, validity, pixel index, per-frame mean and sd of each channel."""
    xd, vd, idd, mu_d, sd_d = depth
    xa, va, ida, mu_a, sd_a = amp
    ld = _depth_log_density(xd - mu_d, pred, idd, sd_d, None)
    if tail is not None:  # the readings' tails about their pixel's centre, as without outliers
        yd = xd - (mu_d - mu_d[:1])  # less the per-frame changes of the means
        dev = yd - pixel_centre(yd, vd, sd_d)
        if pred.wrap is not None:
            dev = dev - pred.wrap * torch.round(dev / pred.wrap)
        var = sd_d * sd_d
        ld = ld + student_log_density(dev, var, tail) - gauss_log_density(dev, var)
    va_tot = sd_a**2 + (tau**2 if isinstance(tau, torch.Tensor) else tau**2)
    la = gauss_log_density(xa - mu_a, va_tot)
    pos = torch.searchsorted(ida, idd)
    lu_d = -math.log(ctx.depth_span)
    lu_a = -math.log(ctx.amp_span)
    log_r = torch.log(torch.as_tensor(rate, dtype=torch.float64))
    log_q = torch.log1p(-torch.as_tensor(rate, dtype=torch.float64))
    # the depth pixels are amplitude pixels too (mask_d is inside mask_a): they share the label
    joint = torch.logaddexp(log_q + ld + la[:, pos], log_r + lu_d + lu_a)
    out = -(joint * vd).sum()
    only_a = torch.ones(ida.numel(), dtype=torch.bool)
    only_a[pos] = False
    if bool(only_a.any()):
        ja = torch.logaddexp(log_q + la[:, only_a], log_r + lu_a)
        out = out - (ja * va[:, only_a]).sum()
    return out
