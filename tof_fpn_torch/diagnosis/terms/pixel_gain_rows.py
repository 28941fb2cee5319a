"""``pixel_gain`` along rows: a free gain per sensor row, fine from row to row (a flexible member
of the ``pixel_gain`` effect).

A real sensor's photo-response non-uniformity is not only a random gain per pixel: a row whose
select or reset line is weaker collects less of the light along its whole length (EMVA 1288
counts row and column non-uniformity in the PRNU; the column gains are the baseline's, from
the read-out's closed-form column pattern, :mod:`~tof_fpn_torch.diagnosis.readout`). The
signature that tells such a row from its neighbours: the amplitude of every pixel of the row
scaled by one factor (a share of the light, as much for bright pixels as for dark ones), the
depth untouched, the same in every frame, and a change from one row to the next (a smooth
change along the rows is the scene's light or a vignette, not a line of the sensor).

Model: per row ``y`` the inverse-variance weighted mean ``b_y`` of the relative amplitude
residual ``m_a / mu_a - 1`` of the model without the member (outliers beyond ``OUTLIER_SIGMA``
sd left out), less its running median over ``2 FINE_SCALE_PX`` rows either side (the part fine from row
to row; a few weak rows do not move a median); the rows' gains a random effect that is 0 in most rows and Gaussian in a share of them (a
few weak lines; in every row, the Gaussian random effect of the read-out's columns), its
share and variance by EM over the rows, every row its posterior mean (empirical Bayes
shrinkage: a row whose mean is noise is pulled to 1). The sum of the rows' shrinkage factors is
the effective number of parameters the AIC counts. The report names it ``pixel_gain``.
"""

from __future__ import annotations

import math

import torch

from ...sim import PixelGain
from ..prediction import predict
from ..readout import OUTLIER_SIGMA, random_effect_variance
from ..signature import FINE_SCALE_PX
from .base import ClosedFormMapTerm, r4

__all__ = ["PixelGainRowsTerm", "row_gains"]

_KEY = "pixel_gain_rows"


def _smooth_rows(x: torch.Tensor, has: torch.Tensor, s: float) -> torch.Tensor:
    """The running median of a row profile ``x`` (H,) over ``2 s`` rows either side (the rows
    ``has`` only; beyond the ends the profile reflected about its end value, so that a slope
    is followed to the end): a smooth change along the rows, which a few weak rows do not
    move."""
    xs = x[has]
    n = xs.numel()
    if n < 3:
        return torch.zeros_like(x)
    r = min(int(round(2 * s)), n - 1)
    head = 2 * xs[:1] - xs[1 : r + 1].flip(0)
    tail = 2 * xs[-1:] - xs[-r - 1 : -1].flip(0)
    win = torch.cat([head, xs, tail]).unfold(0, 2 * r + 1, 1)
    out = torch.zeros_like(x)
    out[has] = win.median(dim=1).values
    return out


def row_gains(rel: torch.Tensor, var: torch.Tensor, ok: torch.Tensor):
    """``(gains (H,), effective parameters)`` of the rows from the relative amplitude residuals
    ``rel`` (H, W), their variances ``var`` and the pixels ``ok`` that enter (module
    docstring)."""
    wt = torch.where(ok & (var > 0), 1.0 / var.clamp_min(1e-300), torch.zeros_like(var))
    sw = wt.sum(1)
    has = sw > 0
    b = torch.where(has, (wt * torch.where(ok, rel, 0.0)).sum(1) / sw.clamp_min(1e-300), 0.0)
    c = torch.where(has, 1.0 / sw.clamp_min(1e-300), torch.full_like(sw, 1e30))
    b = b - _smooth_rows(b, has, FINE_SCALE_PX)
    s2 = random_effect_variance(b[has].view(-1, 1), c[has].view(-1, 1))
    if s2 <= 0:
        return torch.zeros_like(b), 0.0
    p, s2 = _slab_weights(b[has], c[has], s2)
    if s2 <= 0:
        return torch.zeros_like(b), 0.0
    share = torch.zeros_like(c)
    share[has] = p * s2 / (s2 + c[has])
    return share * b, float(share.sum())


def _slab_weights(b: torch.Tensor, c: torch.Tensor, s2: float, steps: int = 50):
    """EM for the prior of the row gains: 0 (a row like the others) with probability ``1 -
    pi``, else Gaussian of variance ``s2`` (a line of the sensor); ``b`` the rows' estimates,
    ``c`` their variances. Returns each row's posterior probability of the second part and
    ``s2``. A few weak rows get ``pi`` near their share; a gain in every row ``pi`` near 1 (the
    Gaussian random effect); rows of noise ``s2`` near 0."""
    pi = 0.5
    p = torch.full_like(b, pi)
    for _ in range(steps):
        v1 = s2 + c
        l1 = math.log(pi) - 0.5 * (torch.log(v1) + b * b / v1)
        l0 = math.log1p(-pi) - 0.5 * (torch.log(c) + b * b / c)
        p = torch.sigmoid(l1 - l0)
        pi = min(max(float(p.mean()), 1.0 / b.numel()), 1.0 - 1e-9)
        s2 = max(float((p * (b * b - c)).sum() / p.sum().clamp_min(1e-300)), 0.0)
        if s2 <= 0:
            break
    return p, s2


def update_rows(model, obs, ctx, pred, sel: str = "all"):
    """``model`` with the row gains estimated on the ``sel`` pixels against the model without
    the member."""
    with torch.no_grad():
        bare = predict(model.without(_KEY), obs, scene=ctx.scene)
        mu = bare.mu_a.detach()
        tau = bare.tau_a.detach() if isinstance(bare.tau_a, torch.Tensor) else bare.tau_a
        var = (bare.sd_a.detach() ** 2 / obs.n.clamp_min(1) + tau**2) / mu.clamp_min(1e-12) ** 2
        rel = obs.m_a / mu.clamp_min(1e-12) - 1.0
        ok = ctx.mask_a & ctx.select(sel) & (obs.n > 0) & (mu > 0) & torch.isfinite(rel)
        ok &= rel.abs() < OUTLIER_SIGMA * var.sqrt()  # not an outlier, a clip, a wrap
        g, dof = row_gains(rel, var, ok)
    out = model.copy()
    out.profiles[_KEY] = (1.0 + g).view(-1, 1).expand(obs.shape).contiguous()
    out.values[f"{_KEY}.dof"] = dof
    return out


class PixelGainRowsTerm(ClosedFormMapTerm):
    """No scalar parameters: the row gains (``model.profiles["pixel_gain_rows"]``, a gain map)
    are estimated in closed form (:func:`update_rows`)."""

    name = "pixel_gain_rows"
    signature = "pixel_gain"
    enters = "chain"
    sim_name = "pixel_gain"
    axes = ("amp_mean|row",)
    about = "a gain per sensor row, fine from row to row (row non-uniformity of the PRNU)"
    profile_keys = (_KEY,)
    gain_map_term = PixelGain

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return update_rows(model, obs, ctx, pred, sel)

    def describe(self, model, obs, pred) -> dict:
        g = model.profiles.get(_KEY)
        if g is None:
            return {"effective_parameters": 0.0}
        rows = g[:, 0] - 1.0
        return {
            "row_gain_rms_percent": r4(100 * math.sqrt(float((rows**2).mean()))),
            "largest_row_loss_percent": r4(-100 * float(rows.min())),
            "effective_parameters": r4(model.values.get(f"{_KEY}.dof", 0.0)),
        }
