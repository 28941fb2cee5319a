"""``temporal_drift``: warm-up, a delay ``D (1 - exp(-t / tau))`` and a light change
``1 + a (1 - exp(-t / tau))`` over the recording; it enters the likelihood per frame."""

from __future__ import annotations

import torch

from ...sim import TemporalDrift
from ..params import SCALE_DEPTH, ParamSpec
from ..signature import common_share
from .base import Term, least_squares, r4

__all__ = ["TemporalDriftTerm"]


class TemporalDriftTerm(Term):
    """``D`` (m), ``a`` and ``tau`` (s, or frames without timestamps); starts: ``tau`` at 0.1,
    0.3, 1 and 3 times the recording's span, ``D`` and ``a`` by least squares on the per-frame
    mean residuals (at least 3 frames)."""

    name = "temporal_drift"
    specs = (
        ParamSpec("temporal_drift.depth_step", "lin", SCALE_DEPTH, "m"),
        ParamSpec("temporal_drift.amplitude_step", "relgain", 0.01),
        ParamSpec("temporal_drift.time_constant", "log", 1.0, "s"),
    )
    enters = "frames"
    sim_name = "temporal_drift"
    axes = ("depth_frame|frame", "amp_frame|frame")
    about = "warm-up: delay D (1 - exp(-t/tau)), light 1 + a (1 - exp(-t/tau))"
    revealed_without_scene = True

    def signature_share(self, obs, ctx, pred):
        """A drift moves a frame's pixels together: the share of the frames' course common to
        their pixels (median against mean)."""
        return common_share(obs, ctx, pred)

    def simulator_term(self, v: dict, model):
        return TemporalDrift(
            v["temporal_drift.depth_step"],
            v["temporal_drift.amplitude_step"],
            v["temporal_drift.time_constant"],
            model.frame_interval,
        )

    def frame_means(self, v: dict, obs, model=None):
        u = (1.0 - torch.exp(-obs.times / v["temporal_drift.time_constant"])).view(obs.frames, 1)
        return u * v["temporal_drift.depth_step"], 1.0 + u * v["temporal_drift.amplitude_step"]

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        if obs.frames < 3:
            return []
        vd = obs.valid & ctx.mask_d
        e = torch.where(vd, (obs.depth - pred.mu_d), torch.zeros_like(obs.depth)).sum((1, 2))
        e = e / vd.sum((1, 2)).clamp_min(1)
        va = obs.valid & ctx.mask_a
        ea = torch.where(va, obs.amplitude / pred.mu_a - 1, torch.zeros_like(obs.amplitude))
        ea = ea.sum((1, 2)) / va.sum((1, 2)).clamp_min(1)
        span = float(obs.times[-1] - obs.times[0]) or 1.0
        out = []
        for f in (0.1, 0.3, 1.0, 3.0):
            u = 1 - torch.exp(-obs.times / (f * span))
            uc, one = u - u.mean(), torch.ones_like(u)
            out.append(
                {
                    "temporal_drift.depth_step": least_squares(uc, e - e.mean(), one),
                    "temporal_drift.amplitude_step": least_squares(uc, ea - ea.mean(), one),
                    "temporal_drift.time_constant": f * span,
                }
            )
        return out

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        return {
            "depth_step_mm": r4(v["temporal_drift.depth_step"] * 1e3),
            "amplitude_step_percent": r4(v["temporal_drift.amplitude_step"] * 100),
            "time_constant": r4(v["temporal_drift.time_constant"]),
            "time_unit": "s" if model.frame_interval != 1.0 else "frames (or s)",
        }
