"""``flying_pixels``: a Gaussian point-spread function mixing the returns of neighbouring pixels
(phasors of different depths at depth edges)."""

from __future__ import annotations

from ...sim import LensBlur
from ..params import ParamSpec
from .base import Term, r4

__all__ = ["FlyingPixelsTerm"]


class FlyingPixelsTerm(Term):
    """PSF sd (px); starts on a grid from 0.25 to 1.2 px."""

    name = "flying_pixels"
    specs = (ParamSpec("flying_pixels.sigma", "log", 1.0, "px"),)
    enters = "chain"
    sim_name = "flying_pixels"
    axes = ("depth_mean|edge",)
    about = "Gaussian PSF mixing the returns of neighbouring pixels at depth edges"

    def simulator_term(self, v: dict, model):
        return LensBlur(v["flying_pixels.sigma"])

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{"flying_pixels.sigma": s} for s in (0.25, 0.4, 0.6, 0.85, 1.2)]

    def describe(self, model, obs, pred) -> dict:
        return {"psf_sigma_px": r4(model.values["flying_pixels.sigma"])}
