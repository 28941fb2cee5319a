"""``impulsive_pixels``: frame-pixels with no information (random-telegraph pixels, gross read-out
errors, defect pixels); every frame-pixel's likelihood becomes a mixture
``(1 - r) N_D N_A + r U_D U_A`` with uniform densities over the observed depth and amplitude
ranges.

What tells them from a misfit of the model (``signature_share``,
:func:`~tof_fpn_torch.diagnosis.signature.sporadic_share`): an impulsive frame-pixel comes and
goes (a telegraph pixel jumps between its levels from frame to frame), or it sits on a defect
pixel: a hot pixel, whose tap collects the dark charge of a crystal defect (thousands of
electrons, growing with the exposure), is fixed in time but rare, independent of its neighbours
and of the scene, and far outside the spread of the other pixels' offsets -- the tail of the
pixels, not a random offset of every one of them."""

from __future__ import annotations

from ...sim import ImpulsivePixels
from ..params import ParamSpec
from ..signature import sporadic_share
from .base import Term, r4

__all__ = ["MAX_IMPULSIVE_RATE", "ImpulsivePixelsTerm"]

#: Largest share of impulsive frame-pixels the mixture may fit.
MAX_IMPULSIVE_RATE: float = 0.5


class ImpulsivePixelsTerm(Term):
    """The rate ``r``; starts at 1e-4, 1e-3 and 1e-2 (at least 2 frames or 100 known pixels)."""

    name = "impulsive_pixels"
    specs = (ParamSpec("impulsive_pixels.rate", "logit", MAX_IMPULSIVE_RATE),)
    enters = "frames"
    sim_name = "impulsive"
    axes = ("depth_tail|pixels", "depth_spread|pixels")
    about = "frame-pixels with no information: a uniform component of the mixture"
    revealed_without_scene = True

    def simulator_term(self, v: dict, model):
        return ImpulsivePixels(
            rate=float(v["impulsive_pixels.rate"]), level=model.impulsive_level, mode="uniform"
        )

    def outlier_rate(self, v: dict):
        return v["impulsive_pixels.rate"]

    def signature_share(self, obs, ctx, pred):
        """Impulsive frame-pixels come and go or sit on isolated defect pixels: the share of the
        outliers that are sporadic or on such pixels."""
        return sporadic_share(obs, ctx, pred)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        if obs.frames < 2 and obs.known.sum() < 100:
            return []
        return [{"impulsive_pixels.rate": r} for r in (1e-4, 1e-3, 1e-2)]

    def describe(self, model, obs, pred) -> dict:
        return {"rate_percent": r4(model.values["impulsive_pixels.rate"] * 100)}
