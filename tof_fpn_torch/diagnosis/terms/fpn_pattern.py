"""``fpn_pattern``: column / row delays of any spectrum, their profiles estimated in closed form.

For a column ``c`` the weighted mean ``m_c`` of the depth residuals (weights ``1 / var`` of the
temporal means, residuals winsorised at 5 sigma) has variance ``sigma_c^2 + 1 / W_c`` around
zero; ``sigma_c^2`` is estimated by moments and every column gets its best linear unbiased
prediction ``m_c sigma_c^2 / (sigma_c^2 + 1 / W_c)`` (the empirical Bayes shrinkage of a random
effect about zero), so that a column whose mean is noise is pulled to zero; the profile keeps its
mean (a delay common to all columns is a delay of the clock tree). Rows likewise, alternating
with the columns. The shrinkage factors sum to the effective number of parameters counted by the
AIC (``values["fpn_pattern.dof"]``). The fit alternates these estimates with L-BFGS on the
other parameters.
"""

from __future__ import annotations

import math

import torch

from ... import constants as K
from ...sim import FPNPattern
from .base import Term, r4, shrink_to_zero

__all__ = ["FPNPatternTerm", "update_profiles"]


def update_profiles(model, obs, ctx, pred, sel: str = "all"):
    """Closed-form (empirical Bayes) column and row delay profiles from the depth residuals."""
    h, w = obs.shape
    m = ctx.mask_d & ctx.select(sel)
    old_c = model.profiles.get("columns", torch.zeros(w, dtype=torch.float64))
    old_r = model.profiles.get("rows", torch.zeros(h, dtype=torch.float64))
    with torch.no_grad():
        var = pred.sd_d.detach() ** 2 / obs.n.clamp_min(1)
        r = obs.m_d - pred.mu_d.detach() + old_c.view(1, w) + old_r.view(h, 1)
        if pred.wrap is not None:
            r = r - pred.wrap * torch.round(r / pred.wrap)
        lim = 5.0 * torch.sqrt(var)
        r = torch.maximum(torch.minimum(r, lim), -lim)
        wt = torch.where(m, 1.0 / var, torch.zeros_like(var))
        col = torch.zeros(w, dtype=torch.float64)
        row = torch.zeros(h, dtype=torch.float64)
        dof = 0.0
        rms = {}
        for _ in range(2):
            for axis, name in ((0, "columns"), (1, "rows")):
                other = row.view(h, 1) if axis == 0 else col.view(1, w)
                res = (r - other) * wt
                big_w = wt.sum(axis)
                has = big_w > 0
                mean = torch.where(has, res.sum(axis) / big_w.clamp_min(1e-300), 0.0)
                noise = torch.where(has, 1.0 / big_w.clamp_min(1e-300), 0.0)
                prof, rms[name], shrink = shrink_to_zero(mean, noise, has)
                if axis == 0:
                    col = prof
                else:
                    row = prof
                if _ == 1:
                    dof += float(shrink.sum()) + 1.0
    out = model.copy()
    out.profiles = {"columns": col, "rows": row}
    out.values["fpn_pattern.dof"] = dof
    out.values["fpn_pattern.rms_columns"] = rms["columns"]
    out.values["fpn_pattern.rms_rows"] = rms["rows"]
    return out


def _near(f: torch.Tensor, centre: float, bw: float) -> torch.Tensor:
    """The frequency bins within ``bw`` of ``centre``."""
    return (f - centre).abs() <= bw


class FPNPatternTerm(Term):
    """No scalar parameters: the profiles (``model.profiles["columns"]``, ``["rows"]``) are
    estimated in closed form (:func:`update_profiles`)."""

    name = "fpn_pattern"
    enters = "chain"
    sim_name = "fpn_pattern"
    axes = ("depth_mean|column", "depth_mean|row")
    about = "column / row delays of any spectrum (profiles estimated in closed form)"
    revealed_without_scene = True
    closed_form = True
    profile_keys = ("columns", "rows")

    def simulator_term(self, v: dict, model):
        return FPNPattern(
            column_profile=model.profiles.get("columns"), row_profile=model.profiles.get("rows")
        )

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{}]

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return update_profiles(model, obs, ctx, pred, sel)

    def effective_parameters(self, values: dict) -> float:
        return float(values.get("fpn_pattern.dof", 0.0))

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        out = {
            "rms_columns_mm": r4(v.get("fpn_pattern.rms_columns", 0.0) * 1e3),
            "rms_rows_mm": r4(v.get("fpn_pattern.rms_rows", 0.0) * 1e3),
            "effective_parameters": r4(v.get("fpn_pattern.dof", 0.0)),
        }
        c = model.profiles.get("columns")
        if c is not None and c.numel() > 8:
            pw = torch.fft.rfft(c - c.mean()).abs()[1:] ** 2
            f = torch.arange(1, pw.numel() + 1, dtype=torch.float64) * (2 * math.pi / c.numel())
            tot = float(pw.sum()) or 1.0
            bw = 1.5 * 2 * math.pi / c.numel()
            near_23 = _near(f, K.FPN_FREQUENCIES[0], bw)
            near_pi = _near(f, math.pi, bw)
            out["profile_power_share_near_2pi/3"] = r4(float(pw[near_23].sum()) / tot)
            out["profile_power_share_near_pi"] = r4(float(pw[near_pi].sum()) / tot)
            out["white_share_of_those_bins"] = r4(float(near_23.sum() + near_pi.sum()) / pw.numel())
        return out
