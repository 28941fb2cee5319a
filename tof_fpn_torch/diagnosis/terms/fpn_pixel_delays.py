"""``fpn_pattern`` per pixel: a delay of each pixel, fixed in time (a flexible member of the
``fpn_pattern`` effect).

A real sensor's phase-offset map (the per-pixel P0 table of a calibration) has column and row
parts and a strong part of its own per pixel: each pixel's tap timing. What that does to the
readings (the signature that tells it from its neighbours):

* the depth mean of each pixel moves by its own delay, at any amplitude (a complex read-out
  offset moves it by ``1 / A``, ``fpn_pixel_offsets``);
* the amplitude does not move (a pixel gain moves only the amplitude);
* the same in every frame: the temporal mean of the residual carries it, the spread about it does
  not (clock jitter or a noise floor is new in each frame).

Model: a random effect on each pixel's depth mean, a delay of sd ``sigma_p`` (m, fitted), which
adds ``sigma_p^2`` to the variance of the depth mean; the column and row parts are the closed-form
profiles of ``fpn_pattern`` when that is in the model too (the two forms of the effect join).
Its held-out gain is scaled by the share of the depth misfit finer than a smoothing (a spread
fits any misfit: a smooth one is another effect's). The report names it ``fpn_pattern``.
"""

from __future__ import annotations

import torch

from ...sim import FPNPattern
from ..params import SCALE_DEPTH, ParamSpec
from ..signature import _fine, both_shares, dense_share
from .base import Term, r4

__all__ = ["FPNPixelDelaysTerm", "fine_depth_share"]

#: starting ``sigma_p`` as multiples of the median sd of a pixel's depth mean
START_FACTORS: tuple[float, ...] = (0.3, 1.0, 3.0)


def fine_depth_share(obs, ctx, pred) -> float | None:
    """Share (0 to 1) of the excess variance of the depth means' residuals that is finer than
    ``signature.FINE_SCALE_PX`` (within the scene's depth layers); None: no excess."""
    m = ctx.mask_d & torch.isfinite(obs.m_d)
    if int(m.sum()) < 16:
        return None
    rd = obs.m_d - pred.mu_d.detach()
    if pred.wrap is not None:
        rd = rd - pred.wrap * torch.round(rd / pred.wrap)
    rd = torch.where(m, rd, 0.0)
    var = pred.sd_d.detach() ** 2 / obs.n.clamp_min(1)
    return _fine([rd], [var], m, obs.scene_depth.to(torch.float64))


class FPNPixelDelaysTerm(Term):
    """``sigma_p`` (m) of the per-pixel delay. Starts: 0.3, 1 and 3 times the median sd of a
    pixel's depth mean."""

    name = "fpn_pixel_delays"
    signature = "fpn_pattern"
    specs = (ParamSpec("fpn_pixel_delays.sd", "rootabs", SCALE_DEPTH, "m"),)
    enters = "variance"
    sim_name = "fpn_pattern"
    axes = ("depth_mean|pixels", "depth_mean|column", "depth_mean|row")
    about = "a delay of each pixel, fixed in time (a per-pixel phase-offset map)"

    def simulator_term(self, v: dict, model):
        return FPNPattern(rms_pixels=abs(float(v["fpn_pixel_delays.sd"])))

    def depth_mean_sd(self, v: dict, a0, k: float):
        return v["fpn_pixel_delays.sd"] * torch.ones_like(a0)

    def signature_share(self, obs, ctx, pred):
        """A delay per pixel: the share of the depth misfit finer than a smoothing, times the
        share of the means' excess spread not carried by isolated defect pixels (a delay map
        of every pixel is dense; :func:`~tof_fpn_torch.diagnosis.signature.dense_share`)."""
        fine = fine_depth_share(obs, ctx, pred)
        dense = dense_share(obs, ctx, pred)
        return both_shares(fine, dense)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        if not bool(ctx.mask_d.any()):
            return []
        s = float((pred.sd_d / obs.n.clamp_min(1).sqrt())[ctx.mask_d].median())
        return [{"fpn_pixel_delays.sd": f * s} for f in START_FACTORS]

    def describe(self, model, obs, pred) -> dict:
        return {"pixel_delay_rms_mm": r4(abs(float(model.values["fpn_pixel_delays.sd"])) * 1e3)}
