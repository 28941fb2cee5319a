"""``noise_floor`` with heavy tails: a flexible member of the noise floor whose readings scatter
with a Student-t law (free degrees of freedom) instead of a Gaussian one.

The catalogue's ``noise_floor`` adds a Gaussian variance to every depth reading. A real clock's
jitter, a ground bounce or a readout that now and then slips need not be Gaussian: most readings
scatter a little more, a few a lot. This member adds the same variance (``sigma``, m) and makes
every depth reading Student-t about its mean with ``dof = 1 / tail`` degrees of freedom, scaled
to the predicted variance (``Term.depth_tail``; ``tail`` in (0, ``MAX_TAIL``), so ``dof > 2.5``:
the floor keeps a finite sd). Its signature is the floor's (a spread in every pixel, extra to
the shot noise and not falling with the amplitude) with a tail that falls off as a power of the
residual: readings a few sd out in depth alone (the amplitude reading as usual), as often in
bright pixels as in dark ones. Impulsive pixels are a small share of readings with any value (a
uniform component): far out, over the whole range, in amplitude as well as in depth.
The report names it ``noise_floor``.
"""

from __future__ import annotations

import math

import torch

from ...sim import PhaseJitter
from ..densities import gauss_log_density, pixel_centre
from ..params import SCALE_DEPTH, ParamSpec
from .base import Term, r4

__all__ = [
    "MAX_TAIL",
    "TAIL_EXCESS_SD",
    "TAIL_RATIO",
    "TAIL_Z",
    "NoiseFloorTailsTerm",
    "far_readings",
]

#: Largest ``1 / dof`` the Student-t law may fit (dof >= 2.5: a finite sd)
MAX_TAIL: float = 0.4
#: The member is tried when ``TAIL_RATIO`` times as many readings lie ``TAIL_Z`` predicted sd
#: from their pixel's temporal mean as a Gaussian law gives, and more by ``TAIL_EXCESS_SD`` of a
#: Poisson count: a tail clearly heavier than a Gaussian's. A Gaussian floor whose sd the model
#: predicts a little off pixel by pixel also has more far readings (1.5 times as many on a null
#: 204 x 204 x 50 recording: a Student-t law fitted them with 130 degrees of freedom and gained
#: 37 nats); a 3-dof jitter at its detection magnitude has 36 times as many.
TAIL_Z: float = 4.0
TAIL_RATIO: float = 3.0
TAIL_EXCESS_SD: float = 4.0


def far_readings(obs, ctx, pred, rate=None) -> tuple[int, float]:
    """``(count, Gaussian expectation)`` of the depth readings of the depth pixels farther than
    ``TAIL_Z`` predicted sd from their pixel's temporal mean (outliers left out of it:
    ``densities.pixel_centre``) that the model's outliers (``rate``: the share of frame-pixels
    with any value, uniform over the observed depth and amplitude ranges) do not claim, both
    channels' readings together: a jitter of the delay moves the phase alone, an impulse (a hot
    pixel, a corrupted raw sample) lands anywhere in depth and in amplitude."""
    t = obs.frames
    ok = (obs.valid & ctx.mask_d & (obs.n > 1)).reshape(t, -1)
    sd = pred.sd_d.detach().clamp_min(1e-12).reshape(1, -1)
    x = torch.where(ok, obs.depth.reshape(t, -1), torch.zeros((), dtype=obs.depth.dtype))
    d = x - pixel_centre(x, ok, sd)
    if pred.wrap is not None:
        d = d - pred.wrap * torch.round(d / pred.wrap)
    far = ok & (d.abs() > TAIL_Z * sd)
    if rate is not None:  # the readings the outliers' uniform law explains better are theirs
        sa = pred.sd_a.detach().clamp_min(1e-12).reshape(1, -1)
        xa = torch.where(ok, obs.amplitude.reshape(t, -1), torch.zeros((), dtype=x.dtype))
        da = xa - pixel_centre(xa, ok, sa)
        r = float(torch.as_tensor(rate).detach())
        inlier = math.log1p(-r) + gauss_log_density(d, sd * sd) + gauss_log_density(da, sa * sa)
        outlier = math.log(r) - math.log(ctx.depth_span) - math.log(ctx.amp_span)
        far &= inlier > outlier
    return int(far.sum()), float(ok.sum()) * math.erfc(TAIL_Z / math.sqrt(2.0))


class NoiseFloorTailsTerm(Term):
    """Jitter sd (m) and ``1 / dof``; starts at 0.5 and 1.5 times the median predicted depth sd
    with 4 degrees of freedom, tried only when the readings have a heavier tail than a Gaussian
    law (:func:`far_readings`)."""

    name = "noise_floor_tails"
    signature = "noise_floor"
    specs = (
        ParamSpec("noise_floor_tails.sigma", "rootabs", SCALE_DEPTH**2, "m"),
        ParamSpec("noise_floor_tails.tail", "logit", MAX_TAIL),
    )
    enters = "frames"
    sim_name = "noise_floor"
    axes = ("depth_spread|amplitude", "depth_tail|pixels", "depth_mean|pixels")
    about = (
        "a heavy-tailed depth noise floor (Student-t readings) that does not fall with amplitude"
    )
    revealed_without_scene = True

    def simulator_term(self, v: dict, model):
        return PhaseJitter(v["noise_floor_tails.sigma"], dof=1.0 / v["noise_floor_tails.tail"])

    def depth_variance(self, v: dict):
        return v["noise_floor_tails.sigma"] ** 2

    def depth_tail(self, v: dict):
        return v["noise_floor_tails.tail"]

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        if obs.frames < 2:
            return []
        rate = next(
            (r for r in (t.outlier_rate(model.values) for t in model.terms) if r is not None),
            None,
        )
        count, expected = far_readings(obs, ctx, pred, rate)
        if (
            count < TAIL_RATIO * expected
            or count <= expected + TAIL_EXCESS_SD * math.sqrt(expected) + 1
        ):
            return []  # no tail heavier than a Gaussian's: nothing for the member to fit
        md = ctx.mask_d
        sd_med = float(pred.sd_d[md].median()) if bool(md.any()) else 1e-3
        return [
            {"noise_floor_tails.sigma": f * sd_med, "noise_floor_tails.tail": 1.0 / 4.0}
            for f in (0.5, 1.5)
        ]

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        return {
            "sigma_mm": r4(v["noise_floor_tails.sigma"] * 1e3),
            "degrees_of_freedom": r4(1.0 / v["noise_floor_tails.tail"]),
        }
