"""``cyclic_error``: a non-sinusoidal correlation; its harmonics ``N - 1`` and ``N + 1`` alias into
the first DFT bin and bend the decoded phase with a period of ``c_L / (2 f N)``."""

from __future__ import annotations

import math

import torch

from ... import constants as K
from ...sim import Camera, CyclicError, SimState, depth_from_samples
from ..params import SCALE_CYCLIC, ParamSpec
from .base import Term, r4

__all__ = ["CyclicErrorTerm", "harmonics", "peak_to_peak"]


def harmonics(n_phases: int) -> tuple[int, int]:
    """The correlation harmonics that alias into the first DFT bin of N samples: N - 1, N + 1."""
    return (n_phases - 1, n_phases + 1)


def peak_to_peak(term, camera: Camera, points: int = 256) -> float:
    """Peak-to-peak depth error (m) of a :class:`~tof_fpn_torch.sim.CyclicError` over a range."""
    n = camera.n_phases
    phi = torch.linspace(0, 2 * math.pi, points + 1, dtype=torch.float64)[:-1].view(1, 1, 1, -1)
    th = torch.arange(n, dtype=torch.float64).view(1, n, 1, 1) * (2 * math.pi / n)
    s = 2.0 + torch.cos(phi + th)
    st = SimState(camera, None, s, None)
    out = term.apply(st).samples
    d, _, _ = depth_from_samples(out, float(camera.modulation_frequency))
    r = K.SPEED_OF_LIGHT_AIR / (2 * float(camera.modulation_frequency))
    err = d[0, 0, 0] - phi[0, 0, 0] * r / (2 * math.pi)
    err = err - r * torch.round(err / r)
    return float(err.max() - err.min())


class CyclicErrorTerm(Term):
    """Cosine and sine coefficients of the two aliasing harmonics (relative to the fundamental),
    started at zero (the fit is linear near it)."""

    name = "cyclic_error"
    specs = tuple(
        ParamSpec(f"cyclic_error.{p}{i}", "lin", SCALE_CYCLIC)
        for i in (1, 2)
        for p in ("cos", "sin")
    )
    enters = "chain"
    sim_name = "cyclic_error"
    axes = ("depth_mean|depth_mod", "depth_mean|depth")
    about = "non-sinusoidal correlation: harmonics N-1 and N+1 alias into the phase"

    def simulator_term(self, v: dict, model):
        return CyclicError(
            harmonics=harmonics(model.camera.n_phases),
            cos_terms=(v["cyclic_error.cos1"], v["cyclic_error.cos2"]),
            sin_terms=(v["cyclic_error.sin1"], v["cyclic_error.sin2"]),
        )

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        return [{f"cyclic_error.{a}{i}": 0.0 for i in (1, 2) for a in ("cos", "sin")}]

    def describe(self, model, obs, pred) -> dict:
        term = self.simulator_term(model.values, model)
        f = float(model.camera.modulation_frequency)
        return {
            "peak_to_peak_mm": r4(peak_to_peak(term, model.camera) * 1e3),
            "period_m": r4(K.SPEED_OF_LIGHT_AIR / (2 * f * model.camera.n_phases)),
            "harmonics": list(term.harmonics),
            "cos_terms": [r4(x) for x in term.cos_terms],
            "sin_terms": [r4(x) for x in term.sin_terms],
        }
