"""``noise_floor``: clock jitter, a depth noise floor that does not fall with the amplitude; its
variance is added to that of every depth reading."""

from __future__ import annotations

from ...sim import PhaseJitter
from ..params import SCALE_DEPTH, ParamSpec
from .base import Term, r4

__all__ = ["NoiseFloorTerm"]


class NoiseFloorTerm(Term):
    """Jitter sd (m); starts at 0.1, 0.5 and 1.5 times the median predicted depth sd."""

    name = "noise_floor"
    specs = (ParamSpec("noise_floor.sigma", "rootabs", SCALE_DEPTH**2, "m"),)
    enters = "variance"
    sim_name = "noise_floor"
    axes = ("depth_spread|amplitude", "depth_mean|pixels")
    about = "clock jitter: a depth noise floor that does not fall with amplitude"
    revealed_without_scene = True

    def simulator_term(self, v: dict, model):
        return PhaseJitter(v["noise_floor.sigma"])

    def depth_variance(self, v: dict):
        return v["noise_floor.sigma"] ** 2

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        md = ctx.mask_d
        sd_med = float(pred.sd_d[md].median()) if bool(md.any()) else 1e-3
        return [{"noise_floor.sigma": f * sd_med} for f in (0.1, 0.5, 1.5)]

    def describe(self, model, obs, pred) -> dict:
        return {"sigma_mm": r4(model.values["noise_floor.sigma"] * 1e3)}
