"""``amplitude_bias``: a signal-dependent delay ``b A_ref / (A + A_ref)`` (the depth of weak
returns drifts by up to ``b``)."""

from __future__ import annotations

import torch

from ...sim import AmplitudeBias
from ..params import SCALE_DEPTH, ParamSpec
from .base import Term, depth_residuals, least_squares, r4

__all__ = ["AmplitudeBiasTerm"]


class AmplitudeBiasTerm(Term):
    """Delay ``b`` (m) and reference amplitude ``A_ref`` (e-); starts: ``A_ref`` at the 10th,
    50th and 90th percentile of the predicted amplitude, ``b`` by least squares on the depth
    residuals."""

    name = "amplitude_bias"
    specs = (
        ParamSpec("amplitude_bias.delay", "lin", SCALE_DEPTH, "m"),
        ParamSpec("amplitude_bias.reference", "log", 1.0, "e-", charge=True),
    )
    enters = "chain"
    sim_name = "amplitude_bias"
    axes = ("depth_mean|amplitude",)
    about = "signal-dependent delay b A_ref / (A + A_ref)"

    def simulator_term(self, v: dict, model):
        return AmplitudeBias(v["amplitude_bias.delay"], v["amplitude_bias.reference"])

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        g = model.values["camera.conversion_gain"]
        rd, wd = depth_residuals(obs, ctx, pred)
        a_e = (pred.a0 * g)[ctx.mask_d]
        out = []
        for q in (0.1, 0.5, 0.9):
            ref = float(torch.quantile(a_e, q))
            b = least_squares(ref / (a_e + ref), rd, wd)
            out.append({"amplitude_bias.delay": b, "amplitude_bias.reference": ref})
        return out

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        g = v["camera.conversion_gain"]
        a = pred.a0[obs.known]
        ref = v["amplitude_bias.reference"]
        lo, hi = (float(torch.quantile(a, q)) * g for q in (0.1, 0.9))
        b = v["amplitude_bias.delay"]
        return {
            "delay_mm": r4(b * 1e3),
            "reference_e": r4(ref),
            "reference_amplitude": r4(ref / g),
            "bias_at_p10_amplitude_mm": r4(b * ref / (lo + ref) * 1e3),
            "bias_at_p90_amplitude_mm": r4(b * ref / (hi + ref) * 1e3),
        }
