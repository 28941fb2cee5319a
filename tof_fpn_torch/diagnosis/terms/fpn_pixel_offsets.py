"""``fpn_pattern`` in the shape of a real read-out: free column offsets and gains in the complex
domain plus a fixed complex offset per pixel (a flexible member of the ``fpn_pattern`` effect).

A real sensor's read-out pattern is an offset map on the raw samples: column structure (the
column amplifiers and ADCs) and a strong per-pixel part (each pixel's taps), the same in every
frame, entering as a complex offset ``O_p`` of the decoded phasor ``(2/N) X_1`` (DN). What it
does to the readings (the signature that tells it from its neighbours):

* the depth mean moves by ``Im(O_p e^{-j phi_p}) / (k A_p)``: most where the amplitude is
  lowest (a delay per column moves every pixel of the column alike; a pixel gain does not move
  the depth at all);
* the amplitude mean moves by ``Re(O_p e^{-j phi_p})``: by the same amount at any amplitude (a
  pixel gain moves it in proportion to ``A_p``);
* the same in every frame (clock jitter or a noise floor is new in each frame).

Model: the column part as the closed-form column offsets and offset-level gains of
:mod:`~tof_fpn_torch.diagnosis.readout` (empirical Bayes per column, its effective degrees of
freedom counted), the pixel part as a random effect: ``O_p`` with i.i.d. components of sd
``sigma_O`` (DN, fitted), which adds ``(sigma_O / (k A_p))^2`` to the variance of the depth mean
and ``sigma_O^2`` to that of the amplitude mean. The report names it ``fpn_pattern``.
"""

from __future__ import annotations

import math

import torch

from ... import constants as K
from ...sim import PixelOffset
from ..params import ParamSpec
from ..readout import READOUT_KEYS, update_readout
from ..signature import both_shares, dense_share, fine_share
from .base import Term, r4

__all__ = ["FPNPixelOffsetsTerm"]


class FPNPixelOffsetsTerm(Term):
    """``sigma_O`` (DN) of the per-pixel complex offset; the column offsets and gains in closed
    form. Starts: ``sigma_O`` at 0.3, 1 and 3 times the noise of one phasor component."""

    name = "fpn_pixel_offsets"
    signature = "fpn_pattern"
    specs = (ParamSpec("fpn_pixel_offsets.sd", "rootabs", 1.0, "DN"),)
    enters = "variance"
    sim_name = "pixel_offset"
    axes = ("depth_mean|column", "depth_mean|pixels", "amp_mean|pixels", "depth_mean|amplitude")
    about = "complex read-out offsets: free per column, random per pixel (fixed in time)"
    closed_form = True
    profile_keys = READOUT_KEYS

    def simulator_term(self, v: dict, model):
        # the column part is in the baseline's ReadoutFPN (its offset / gain maps)
        g = float(v["camera.conversion_gain"])
        return PixelOffset(sd=float(v["fpn_pixel_offsets.sd"]) * g)

    def depth_mean_sd(self, v: dict, a0, k: float):
        return v["fpn_pixel_offsets.sd"] / (k * a0)

    def amplitude_sd(self, v: dict, mu_a):
        return v["fpn_pixel_offsets.sd"] * torch.ones_like(mu_a)

    def update_closed_form(self, model, obs, ctx, pred, sel: str):
        return update_readout(model, obs, ctx, pred, sel)

    def effective_parameters(self, values: dict) -> float:
        return float(values.get("readout_fpn.columns_dof", 0.0))

    def signature_share(self, obs, ctx, pred):
        """Offsets per pixel and column: the share of the phasor's misfit finer than a
        smoothing, times the share of the means' excess spread not carried by isolated defect
        pixels (a random offset of every pixel is dense; a few hot pixels far outside the
        pattern's spread are outliers, :func:`~tof_fpn_torch.diagnosis.signature.dense_share`)."""
        fine = fine_share(obs, ctx, pred, phasor=True)
        dense = dense_share(obs, ctx, pred)
        return both_shares(fine, dense)

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        s = float(pred.s[ctx.mask_d].median()) if bool(ctx.mask_d.any()) else 1.0
        return [{"fpn_pixel_offsets.sd": f * s} for f in (0.3, 1.0, 3.0)]

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        k = 4 * math.pi * float(model.camera.modulation_frequency) / K.SPEED_OF_LIGHT_AIR
        a = pred.a0[obs.known]
        med = float(a.median()) if a.numel() else float("nan")
        off = model.profiles.get(READOUT_KEYS[0])
        col = float(off.pow(2).sum(0).mean().sqrt()) if off is not None else 0.0
        return {
            "pixel_offset_rms_dn": r4(v["fpn_pixel_offsets.sd"] * math.sqrt(2)),
            "column_offset_rms_dn": r4(col),
            "pixel_depth_rms_at_median_amplitude_mm": r4(
                v["fpn_pixel_offsets.sd"] / (k * med) * 1e3
            ),
            "effective_parameters": r4(v.get("readout_fpn.columns_dof", 0.0)),
        }
