"""``pixel_gain``: photo-response non-uniformity (PRNU, EMVA 1288), a random gain per pixel; it
adds ``(rms A)^2`` to the variance of each pixel's amplitude mean. Without a scene the baseline
holds it from the start: each pixel's amplitude then carries its own reflectance, and
reflectance texture and pixel gain cannot be told apart."""

from __future__ import annotations

from ...sim import PixelGain
from ..params import SCALE_CYCLIC, ParamSpec
from ..signature import both_shares, dense_share, fine_share
from .base import Term, r4

__all__ = ["TEXTURE_RMS", "PixelGainTerm"]

#: Starting rms of the per-pixel amplitude texture of the estimated-scene baseline.
TEXTURE_RMS: float = 0.02


class PixelGainTerm(Term):
    """Gain rms (relative); starts at 0.2, 1 and 3 %."""

    name = "pixel_gain"
    specs = (ParamSpec("pixel_gain.rms", "rootabs", SCALE_CYCLIC**2),)
    enters = "variance"
    sim_name = "pixel_gain"
    axes = ("amp_mean|pixels",)
    about = "photo-response non-uniformity (PRNU), a random gain per pixel"

    def simulator_term(self, v: dict, model):
        return PixelGain(v["pixel_gain.rms"])

    def amplitude_sd(self, v: dict, mu_a):
        return v["pixel_gain.rms"] * mu_a

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{"pixel_gain.rms": r} for r in (0.002, 0.01, 0.03)]

    def signature_share(self, obs, ctx, pred):
        """A gain per pixel: the share of the amplitude misfit finer than a smoothing, times the
        share of the means' excess spread not carried by isolated defect pixels (a gain of every
        pixel is dense; :func:`~tof_fpn_torch.diagnosis.signature.dense_share`)."""
        fine = fine_share(obs, ctx, pred)
        dense = dense_share(obs, ctx, pred)
        return both_shares(fine, dense)

    def describe(self, model, obs, pred) -> dict:
        return {"rms_percent": r4(model.values["pixel_gain.rms"] * 100)}

    def baseline_without_scene(self):
        note = (
            "the baseline holds a per-pixel amplitude texture (pixel_gain): without a "
            "scene, reflectance texture and pixel gain cannot be told apart"
        )
        return {"pixel_gain.rms": TEXTURE_RMS}, note
