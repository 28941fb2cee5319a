"""``temporal_drift`` in the shape of the data: a free delay and light level per frame, estimated
in closed form (a flexible member of the ``temporal_drift`` effect).

A camera's drift has its own course in time (a warm-up, an oscillating regulator, a step when a
fan starts); the catalogue's ``D (1 - exp(-t / tau))`` holds only the first. This member fits
the course itself: for frame ``t`` the weighted mean ``e_t`` of the depth residuals of all depth
pixels (weights ``1 / sd^2``, residuals winsorised at 5 sd) has variance ``sigma^2 + 1 / W_t``
about zero; ``sigma^2`` is estimated by moments and every frame gets the best linear unbiased
prediction ``e_t sigma^2 / (sigma^2 + 1 / W_t)`` (empirical Bayes shrinkage, as the column
profiles of ``fpn_pattern``), the light level likewise from the amplitude's relative residuals.
The shrinkage factors sum to the effective number of parameters the AIC counts. Its signature
is the effect's: every pixel of a frame moves together, the same whatever its depth, amplitude
or place; the report names it ``temporal_drift``.
"""

from __future__ import annotations

import torch

from ...sim import TemporalDrift
from ..signature import common_share
from .base import Term, r4, shrink_to_zero

__all__ = ["TemporalDriftFramesTerm", "frame_profiles"]


def frame_profiles(model, obs, ctx, pred, sel: str = "all", skip: str = ""):
    """``model`` with the closed-form per-frame delays and light levels (``model.profiles``
    ``"frame_delays"``, ``"frame_light"``) from the residuals of the ``sel`` pixels to ``pred``
    and the other per-frame terms of the model (not the one named ``skip``)."""
    v = model.values
    shift = torch.zeros(obs.frames, 1, dtype=torch.float64)
    factor = torch.ones(obs.frames, 1, dtype=torch.float64)
    for t in model.terms:
        if t.name == skip:
            continue
        x = t.frame_means(v, obs, model)
        if x is not None:
            shift, factor = shift + x[0].detach(), factor * x[1].detach()
    with torch.no_grad():
        md = (obs.valid & (ctx.mask_d & ctx.select(sel)).unsqueeze(0)).to(torch.float64)
        var = (pred.sd_d.detach() ** 2).unsqueeze(0)
        r = torch.nan_to_num(obs.depth - pred.mu_d.detach().unsqueeze(0) - shift.view(-1, 1, 1))
        if pred.wrap is not None:
            r = r - pred.wrap * torch.round(r / pred.wrap)
        lim = 5.0 * torch.sqrt(var)
        r = torch.maximum(torch.minimum(r, lim), -lim)
        wd = md / var
        big = wd.sum((1, 2)).clamp_min(1e-300)
        delays, rms_d, dof_d = shrink_to_zero((r * wd).sum((1, 2)) / big, 1.0 / big)
        ma = (obs.valid & (ctx.mask_a & ctx.select(sel)).unsqueeze(0)).to(torch.float64)
        mu_a = pred.mu_a.detach().unsqueeze(0) * factor.view(-1, 1, 1)
        ra = torch.nan_to_num(obs.amplitude / mu_a - 1.0)
        va = (pred.sd_a.detach().unsqueeze(0) / mu_a) ** 2
        lim = 5.0 * torch.sqrt(va)
        ra = torch.maximum(torch.minimum(ra, lim), -lim)
        wa = ma / va
        big = wa.sum((1, 2)).clamp_min(1e-300)
        light, rms_a, dof_a = shrink_to_zero((ra * wa).sum((1, 2)) / big, 1.0 / big)
    out = model.copy()
    out.profiles = dict(out.profiles, frame_delays=delays, frame_light=light)
    out.values["temporal_drift_frames.dof"] = float(dof_d.sum() + dof_a.sum())
    out.values["temporal_drift_frames.rms_delay"] = rms_d
    out.values["temporal_drift_frames.rms_light"] = rms_a
    return out


class TemporalDriftFramesTerm(Term):
    """No scalar parameters: the per-frame profiles (``model.profiles["frame_delays"]``,
    ``["frame_light"]``) are estimated in closed form (:func:`frame_profiles`)."""

    name = "temporal_drift_frames"
    signature = "temporal_drift"
    enters = "frames"
    sim_name = "temporal_drift"
    axes = ("depth_frame|frame", "amp_frame|frame")
    about = "a drift of any course in time: a free delay and light level per frame"
    revealed_without_scene = True
    closed_form = True
    profile_keys = ("frame_delays", "frame_light")

    def signature_share(self, obs, ctx, pred):
        """A drift moves a frame's pixels together: the share of the frames' course common to
        their pixels (median against mean)."""
        return common_share(obs, ctx, pred)

    def frame_means(self, v: dict, obs, model=None):
        if model is None or "frame_delays" not in model.profiles:
            return None
        d = model.profiles["frame_delays"]
        if d.numel() != obs.frames:
            return None
        return d.view(-1, 1), 1.0 + model.profiles["frame_light"].view(-1, 1)

    def simulator_term(self, v: dict, model):
        d = model.profiles.get("frame_delays")
        if d is None:
            return None
        g = model.profiles["frame_light"]
        return TemporalDrift(
            frame_delays=tuple(float(x) for x in d), frame_light=tuple(float(x) for x in g)
        )

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{}] if obs.frames >= 3 else []

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return frame_profiles(model, obs, ctx, pred, sel, skip=self.name)

    def effective_parameters(self, values: dict) -> float:
        return float(values.get("temporal_drift_frames.dof", 0.0))

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        d = model.profiles.get("frame_delays", torch.zeros(1, dtype=torch.float64))
        return {
            "rms_delay_mm": r4(v.get("temporal_drift_frames.rms_delay", 0.0) * 1e3),
            "rms_light_percent": r4(v.get("temporal_drift_frames.rms_light", 0.0) * 100),
            "peak_to_peak_delay_mm": r4(float(d.max() - d.min()) * 1e3),
            "effective_parameters": r4(v.get("temporal_drift_frames.dof", 0.0)),
        }
