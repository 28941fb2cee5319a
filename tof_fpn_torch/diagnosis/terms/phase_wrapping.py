"""``phase_wrapping``: the depth folded into the unambiguous range ``[0, R)`` (no simulator term:
the simulated camera's modulation frequency becomes ``c_L / (2 R)``)."""

from __future__ import annotations

from ... import constants as K
from ..params import ParamSpec
from .base import Term, r4

__all__ = ["PhaseWrappingTerm"]


class PhaseWrappingTerm(Term):
    """The range ``R`` (m); starts at the recording's stated range and at the median gap of the
    pixels read far short of their scene depth (at least 3 of them)."""

    name = "phase_wrapping"
    specs = (ParamSpec("phase_wrapping.range", "log", 1.0, "m"),)
    enters = "wrap"
    sim_name = None
    axes = ("depth_mean|depth",)
    about = "depth folded into the unambiguous range [0, R)"

    def simulator_term(self, v: dict, model):
        return None

    def wrap_range(self, v: dict):
        return v["phase_wrapping.range"]

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        out = []
        if obs.frequency is not None:
            out.append({"phase_wrapping.range": K.SPEED_OF_LIGHT_AIR / (2 * obs.frequency)})
        gap = (pred.mu_d - obs.m_d)[ctx.mask_d]
        big = gap > 0.25 * float(obs.scene_depth[obs.known].max())
        if int(big.sum()) >= 3:
            out.append({"phase_wrapping.range": float(gap[big].median())})
        return out

    def describe(self, model, obs, pred) -> dict:
        rng = model.values["phase_wrapping.range"]
        return {
            "range_m": r4(rng),
            "modulation_frequency_mhz": r4(K.SPEED_OF_LIGHT_AIR / (2 * rng) / 1e6),
            "share_of_pixels_beyond": r4(
                float((obs.scene_depth[obs.known] >= rng).double().mean())
            ),
        }
