"""Locate the mismatch: residual statistics along the axes physics acts on, tested against their
null distribution under the fitted model.

Channels (per pixel, EMVA 1288's split): ``depth_mean`` / ``amp_mean`` -- the temporal mean's
standardised residual ``z = (m - mu) / sqrt(sigma^2 / n + tau^2)``; ``depth_spread`` /
``amp_spread`` -- the temporal variance as ``z`` by the Wilson-Hilferty transform of
``M2 / sigma^2 ~ chi^2_{n-1}`` (T >= 2). Each is binned along every axis of
:mod:`~tof_fpn_torch.diagnosis.axes`; the statistic ``S = sum_b n_b zbar_b^2`` is
``chi^2_{bins}`` when the model is right. Frame axis: ``S = sum_t (sum_p z_tp)^2 / n_t`` over the
frames (T >= 3). Tails: the count of frame-pixels with ``|z| > 5`` and of invalid frame-pixels
where the model predicts a clear signal (Poisson).

Null: a parametric bootstrap from the simulator -- ``B`` recordings of the fitted model (the full
noisy chain: Poisson-like shot noise, read noise, ADC rounding, the stored quantisation; the scene
re-estimated when it was estimated) give each ``S`` its null scale ``c = mean(S_boot) / df``, and
``p = P(c chi^2_df > S)`` (for counts, Poisson with the bootstrap mean). A statistic is
significant below ``alpha / J`` (Bonferroni over the ``J`` statistics).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .. import constants as K
from .axes import Axis, axes
from .data import Observations, fold, pixel_stats
from .threads import map_threads

__all__ = ["ALPHA", "MIN_NULL_SCALE", "TAIL_Z", "Stat", "bootstrap", "locate", "statistics"]

#: Family-wise false-alarm probability of the located statistics (Bonferroni over all of them).
ALPHA: float = 0.01
#: Smallest null scale (bootstrap mean / df) a chi^2 statistic may get.
MIN_NULL_SCALE: float = 0.25
#: A frame-pixel further than this many sigma from the model is a tail event.
TAIL_Z: float = 5.0


@dataclass
class Stat:
    """One located statistic: ``key`` (``channel|axis``), value ``S``, ``df``; per bin the mean
    standardised residual ``zbar``, count ``n`` and mean physical residual ``phys``; bootstrap
    values ``null``; ``p`` and ``significant`` after :func:`locate`."""

    key: str
    value: float
    df: float
    zbar: torch.Tensor | None = None
    n: torch.Tensor | None = None
    phys: torch.Tensor | None = None
    axis: Axis | None = None
    se2: torch.Tensor | None = None
    kind: str = "chi2"
    null: list = field(default_factory=list)
    p: float = 1.0
    significant: bool = False

    @property
    def scale(self) -> float:
        if self.kind != "chi2" or not self.null:
            return 1.0
        return max(sum(self.null) / len(self.null) / max(self.df, 1e-9), MIN_NULL_SCALE)

    def band(self, q: float = 0.95) -> tuple[float, float]:
        """The null's central ``q`` interval of ``S`` (scaled chi^2 or Poisson)."""
        c = self.scale
        if self.kind == "chi2":
            k = self.df
            lo = c * k * (1 - 2 / (9 * k) - 1.96 * math.sqrt(2 / (9 * k))) ** 3
            hi = c * k * (1 - 2 / (9 * k) + 1.96 * math.sqrt(2 / (9 * k))) ** 3
            return max(lo, 0.0), hi
        lam = self._lam()
        return max(lam - 1.96 * math.sqrt(lam), 0.0), lam + 1.96 * math.sqrt(lam)

    @property
    def excess(self) -> float:
        """``(S / c - df) / sqrt(2 df)``: how many null standard deviations ``S`` is above its
        null mean (counts: ``(S - lambda) / sqrt(lambda)``)."""
        if self.kind == "chi2":
            return (self.value / self.scale - self.df) / math.sqrt(2 * max(self.df, 1e-9))
        lam = self._lam()
        return (self.value - lam) / math.sqrt(lam)

    def _lam(self) -> float:
        return max(sum(self.null) / max(len(self.null), 1), 0.5)

    def pvalue(self) -> float:
        if self.kind == "chi2":
            x = torch.tensor(self.value / (2 * self.scale), dtype=torch.float64)
            return float(torch.special.gammaincc(torch.tensor(self.df / 2, dtype=torch.float64), x))
        if self.value < 1:
            return 1.0
        k = torch.tensor(float(self.value), dtype=torch.float64)
        return float(torch.special.gammainc(k, torch.tensor(self._lam(), dtype=torch.float64)))


def _wilson_hilferty(m2, var, n):
    k = (n - 1).clamp_min(1)
    x = (m2 / var / k).clamp_min(1e-12)
    return (x ** (1 / 3) - (1 - 2 / (9 * k))) / torch.sqrt(2 / (9 * k))


def _binned(z, phys, lab: torch.Tensor, nb: int):
    m = lab >= 0
    idx = lab[m]
    n = torch.zeros(nb, dtype=torch.float64).index_add_(0, idx, torch.ones_like(z[m]))
    sz = torch.zeros(nb, dtype=torch.float64).index_add_(0, idx, z[m])
    sp = torch.zeros(nb, dtype=torch.float64).index_add_(0, idx, phys[m])
    # squared standard error of each pixel's physical residual (phys / z), for the null band
    se = torch.where(z[m].abs() > 1e-12, phys[m] / z[m], torch.zeros_like(z[m])) ** 2
    s2 = torch.zeros(nb, dtype=torch.float64).index_add_(0, idx, se)
    zbar = sz / n.clamp_min(1)
    nn_ = n.clamp_min(1)
    return zbar, n, sp / nn_, float((n * zbar * zbar).sum()), int((n > 0).sum()), s2 / nn_


def channels(obs: Observations, pred, ctx) -> dict:
    """Per-pixel ``(z, physical residual, mask)`` of every channel."""
    with torch.no_grad():
        out = {}
        r = obs.m_d - pred.mu_d
        if pred.wrap is not None:
            r = r - pred.wrap * torch.round(r / pred.wrap)
        n = obs.n.clamp_min(1)
        out["depth_mean"] = (r / torch.sqrt(pred.sd_d**2 / n + pred.tau_d**2), r, ctx.mask_d)
        tau2 = pred.tau_a**2
        ra = obs.m_a - pred.mu_a
        out["amp_mean"] = (ra / torch.sqrt(pred.sd_a**2 / n + tau2), ra / pred.mu_a, ctx.mask_a)
        if obs.frames >= 2:
            two = obs.n >= 2
            sdd = torch.sqrt(obs.m2_d / (obs.n - 1).clamp_min(1)) / pred.sd_d
            out["depth_spread"] = (
                _wilson_hilferty(obs.m2_d, pred.sd_d**2, n),
                sdd,
                ctx.mask_d & two,
            )
            sda = torch.sqrt(obs.m2_a / (obs.n - 1).clamp_min(1)) / pred.sd_a
            out["amp_spread"] = (_wilson_hilferty(obs.m2_a, pred.sd_a**2, n), sda, ctx.mask_a & two)
    return out


def statistics(obs: Observations, pred, ctx) -> dict[str, Stat]:
    """Every located statistic of ``obs`` under ``pred`` (no p-values yet)."""
    out = {}
    ch = channels(obs, pred, ctx)
    ax_d = axes(obs, pred, ctx.mask_d)
    ax_a = axes(obs, pred, ctx.mask_a)
    for cname, (z, phys, mask) in ch.items():
        axs = ax_d if cname.startswith("depth") else ax_a
        for aname, ax in axs.items():
            lab = torch.where(mask, ax.labels, -1)
            nb = ax.centres.numel()
            zbar, n, pb, s, df, se2 = _binned(z.masked_fill(~mask, 0.0), phys, lab, nb)
            out[f"{cname}|{aname}"] = Stat(f"{cname}|{aname}", s, df, zbar, n, pb, ax, se2)
    with torch.no_grad():
        if obs.frames >= 3:
            for cname, x, mu, sd, mask in (
                ("depth_frame", obs.depth, pred.mu_d, pred.sd_d, ctx.mask_d),
                ("amp_frame", obs.amplitude, pred.mu_a, pred.sd_a, ctx.mask_a),
            ):
                r = x - mu
                if cname == "depth_frame" and pred.wrap is not None:
                    r = r - pred.wrap * torch.round(r / pred.wrap)
                v = obs.valid & mask
                z = torch.where(v, r / sd, torch.zeros_like(r))
                cnt = v.sum((1, 2)).double().clamp_min(1)
                zt = z.sum((1, 2)) / cnt
                phys = torch.where(v, r, torch.zeros_like(r)).sum((1, 2)) / cnt
                if cname == "amp_frame":
                    phys = phys / mu[mask].mean()
                ax = Axis("frame", torch.empty(0), obs.times.clone(), "s", [])
                s = float((zt * zt * cnt).sum())
                out[f"{cname}|frame"] = Stat(f"{cname}|frame", s, obs.frames, zt, cnt, phys, ax)
        r = obs.depth - pred.mu_d
        if pred.wrap is not None:
            r = r - pred.wrap * torch.round(r / pred.wrap)
        v = obs.valid & ctx.mask_d
        big = (v & ((r / pred.sd_d).abs() > TAIL_Z)).sum()
        out["depth_tail|pixels"] = Stat("depth_tail|pixels", float(big), 1, kind="count")
        clear = ctx.mask_d.unsqueeze(0).expand_as(obs.valid)
        out["invalid|pixels"] = Stat(
            "invalid|pixels", float((clear & ~obs.valid).sum()), 1, kind="count"
        )
    return out


def simulate_observations(model, obs: Observations, ctx, seed: int):
    """One bootstrap recording of ``model`` seen as :class:`Observations` (same masks, scene)."""
    from .data import estimate_scene
    from .prediction import predict

    sim = model.simulation()
    scene32 = ctx.scene.to(dtype=torch.float32)
    out = sim.run(scene32, obs.frames, seed=seed)
    d = out.depth[:, 0].double()
    a = out.amplitude[:, 0].double()
    if obs.q_depth > 0:
        d = torch.round(d / obs.q_depth) * obs.q_depth
    if obs.q_amp > 0:
        a = torch.round(a / obs.q_amp) * obs.q_amp
    valid = torch.isfinite(d) & (d > 0) & torch.isfinite(a)
    period = None if obs.frequency is None else K.SPEED_OF_LIGHT_AIR / (2 * obs.frequency)
    d = torch.where(valid, d, torch.full_like(d, math.nan))
    folded = fold(d, valid, period)
    n, m_d, m2_d = pixel_stats(folded, valid)
    _, m_a, m2_a = pixel_stats(a, valid)
    b = Observations(
        folded,
        torch.where(valid, a, torch.full_like(a, math.nan)),
        valid,
        n,
        m_d,
        m2_d,
        m_a,
        m2_a,
        obs.scene_depth,
        obs.reflectance,
        obs.known & (n > 0),
        obs.scene_estimated,
        obs.frequency,
        obs.n_phases,
        obs.integration_time,
        obs.times,
        obs.q_depth,
        obs.q_amp,
        obs.amplitude_unit,
    )
    if obs.scene_estimated:
        sd, rf, kn = estimate_scene(b)
        b.scene_depth, b.reflectance = sd, rf
        with torch.no_grad():
            pred = predict(model, b, scene=b.scene())
    else:
        with torch.no_grad():
            pred = predict(model, obs, scene=ctx.scene)
    return b, pred


def bootstrap(model, obs: Observations, ctx, stats: dict[str, Stat], replicates: int, seed: int):
    """Fill ``stat.null`` with ``replicates`` parametric-bootstrap values of every statistic."""

    def one(i: int) -> dict:
        b, pred = simulate_observations(model, obs, ctx, seed + 1000 * (i + 1))
        return statistics(b, pred, ctx)

    for sb in map_threads(one, list(range(replicates))):  # own generators: any order, same values
        for k, s in stats.items():
            if k in sb:
                s.null.append(sb[k].value)


def locate(stats: dict[str, Stat], alpha: float = ALPHA) -> list[Stat]:
    """p-values of every statistic; the significant ones, most significant first."""
    j = max(len(stats), 1)
    for s in stats.values():
        s.p = s.pvalue()
        s.significant = s.p < alpha / j
    sig = [s for s in stats.values() if s.significant]
    return sorted(sig, key=lambda s: (s.p, -s.excess))
