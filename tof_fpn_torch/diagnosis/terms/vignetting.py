"""``vignetting``: lens fall-off of the light, ``1 + a2 r^2 + a4 r^4`` about a fitted centre."""

from __future__ import annotations

import torch

from ...sim import Vignetting
from ..params import ParamSpec
from .base import Term, least_squares, r4

__all__ = ["VignettingTerm"]


class VignettingTerm(Term):
    """``a2``, ``a4`` and the centre (px from the frame centre); ``a2`` starts from least squares
    of the amplitude ratio on ``r^2``."""

    name = "vignetting"
    specs = (
        ParamSpec("vignetting.quadratic", "lin", 0.1),
        ParamSpec("vignetting.quartic", "lin", 0.1),
        ParamSpec("vignetting.centre_x", "lin", 10.0, "px"),
        ParamSpec("vignetting.centre_y", "lin", 10.0, "px"),
    )
    enters = "chain"
    sim_name = "vignetting"
    axes = ("amp_mean|radius",)
    about = "lens fall-off 1 + a2 r^2 + a4 r^4 about a fitted centre"

    def simulator_term(self, v: dict, model):
        return Vignetting(
            v["vignetting.quadratic"],
            v["vignetting.quartic"],
            v["vignetting.centre_x"],
            v["vignetting.centre_y"],
        )

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        ma = ctx.mask_a
        h, w = obs.shape
        yy = torch.arange(h, dtype=torch.float64).view(h, 1) - (h - 1) / 2
        xx = torch.arange(w, dtype=torch.float64).view(1, w) - (w - 1) / 2
        r2 = ((xx**2 + yy**2) / (((h - 1) / 2) ** 2 + ((w - 1) / 2) ** 2))[ma]
        ratio = (obs.m_a / pred.mu_a)[ma] - 1.0
        a2 = least_squares(r2 - r2.mean(), ratio - ratio.mean(), torch.ones_like(r2))
        a2 = min(max(a2, -0.8), 0.8)
        return [
            {
                "vignetting.quadratic": a2,
                "vignetting.quartic": 0.0,
                "vignetting.centre_x": 0.0,
                "vignetting.centre_y": 0.0,
            }
        ]

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        vt = self.simulator_term(v, model)
        h, w = obs.shape
        gain = vt.gain(h, w, pred.a0)[0, 0]
        return {
            "quadratic": r4(v["vignetting.quadratic"]),
            "quartic": r4(v["vignetting.quartic"]),
            "centre_px": [r4(v["vignetting.centre_x"]), r4(v["vignetting.centre_y"])],
            "corner_relative_illumination_percent": r4(
                100 * float(gain[[0, 0, -1, -1], [0, -1, 0, -1]].mean()) / float(gain.max())
            ),
        }
