"""``amplitude_bias`` in the shape of the data: a delay that falls monotonically with the
amplitude, piecewise linear in ``ln A`` (a flexible member of the ``amplitude_bias`` effect).

A camera's signal-dependent delay has its own curve (an exponential fade, a power law, a knee):
the catalogue's hyperbola ``b A_ref / (A + A_ref)`` misses most of them. This member fits the
curve itself: knots ``t_0 < ... < t_K`` at the 2nd, 25th, 50th, 75th and 98th percentile of the
predicted amplitude (e-) of the depth pixels (or, for a bias the weakest pixels carry, at the
0.5th, 2nd, 5th, 12th and 30th: both sets are starts, the better one kept), and the delay at
knot ``j``

    D_j = b * (w_{j+1} + ... + w_K) / (w_1 + ... + w_K),     w_k >= 0

so ``D_0 = b`` at the weakest pixels, ``D_K = 0`` at the strongest and the curve never rises
between them (a bias that fades with amplitude, of either sign); linear in ``ln A`` between the
knots, constant beyond. Five parameters (``b`` and the four segment weights; the AIC counts
five). The report names it ``amplitude_bias``: the signature (a depth error that follows the
amplitude alone), not the form.
"""

from __future__ import annotations

import torch

from ...sim import AmplitudeBias
from ..params import SCALE_DEPTH, ParamSpec
from .base import Term, depth_residuals, least_squares, r4

__all__ = ["KNOT_QUANTILES", "AmplitudeBiasShapeTerm"]

#: quantiles of the predicted amplitude of the depth pixels where the knots sit
KNOT_QUANTILES: tuple[float, ...] = (0.02, 0.25, 0.5, 0.75, 0.98)
#: the knots of the starts for a bias the weakest pixels carry (an exponential fade over the
#: weakest few per cent): the curve falls within the weakest third and is zero above it
LOW_KNOT_QUANTILES: tuple[float, ...] = (0.005, 0.02, 0.05, 0.12, 0.3)
_SEGMENTS = len(KNOT_QUANTILES) - 1
_W = tuple(f"amplitude_bias_shape.w{k}" for k in range(1, _SEGMENTS + 1))
_KNOTS = tuple(f"amplitude_bias_shape.knot{j}" for j in range(_SEGMENTS + 1))


def node_delays(v: dict) -> list:
    """The delay (m) at each knot from values ``v`` (floats or tensors)."""
    w = [v[k] for k in _W]
    tot = sum(w[1:], w[0]) + 1e-12
    out, tail = [], 0.0
    for k in range(_SEGMENTS, 0, -1):
        out.append(v["amplitude_bias_shape.delay"] * tail / tot)
        tail = tail + w[k - 1]
    out.append(v["amplitude_bias_shape.delay"] * tail / tot)
    return out[::-1]


class AmplitudeBiasShapeTerm(Term):
    """Delay ``b`` (m) at the weakest pixels and the segment weights ``w_k``; starts: ``b`` by
    least squares on the depth residuals for three shapes on the spread knots (even fall, all of
    it in the weakest quarter, all of it above the median) and two on the weak knots (even fall
    over the weakest 30 %, all of it in the weakest 5 %)."""

    name = "amplitude_bias_shape"
    signature = "amplitude_bias"
    specs = (ParamSpec("amplitude_bias_shape.delay", "lin", SCALE_DEPTH, "m"),) + tuple(
        ParamSpec(k, "abs", 1.0) for k in _W
    )
    enters = "chain"
    sim_name = "amplitude_bias"
    axes = ("depth_mean|amplitude",)
    about = "signal-dependent delay of any monotone curve in ln A (piecewise linear)"

    def simulator_term(self, v: dict, model):
        knots = tuple(float(v[k]) for k in _KNOTS)
        return AmplitudeBias(knots=knots, delays=tuple(node_delays(v)))

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        g = model.values["camera.conversion_gain"]
        rd, wd = depth_residuals(obs, ctx, pred)
        a_e = (pred.a0 * g)[ctx.mask_d]
        if a_e.numel() < 10:
            return []
        out = []
        for quantiles, shapes in (
            (
                KNOT_QUANTILES,
                ((1.0, 1.0, 1.0, 1.0), (1.0, 0.05, 0.05, 0.05), (0.05, 0.05, 1.0, 1.0)),
            ),
            (LOW_KNOT_QUANTILES, ((1.0, 1.0, 1.0, 1.0), (1.0, 1.0, 0.05, 0.05))),
        ):
            qs = torch.tensor(quantiles, dtype=a_e.dtype)
            q = [float(x) for x in torch.quantile(a_e, qs)]
            for j in range(1, len(q)):  # strictly increasing (a flat amplitude: 1 % apart)
                q[j] = max(q[j], 1.01 * q[j - 1])
            knots = dict(zip(_KNOTS, q, strict=True))
            for w in shapes:
                v = dict(knots, **dict(zip(_W, w, strict=True)))
                v["amplitude_bias_shape.delay"] = 1.0
                shape = self.simulator_term(v, model).bias(a_e)
                v["amplitude_bias_shape.delay"] = least_squares(shape, rd, wd)
                out.append(v)
        return out

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        d = node_delays(v)
        g = v["camera.conversion_gain"]
        return {
            "delay_mm": r4(v["amplitude_bias_shape.delay"] * 1e3),
            "knots_amplitude": [r4(float(v[k]) / g) for k in _KNOTS],
            "delays_at_knots_mm": [r4(float(x) * 1e3) for x in d],
        }
