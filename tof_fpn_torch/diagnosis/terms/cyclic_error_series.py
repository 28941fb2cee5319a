"""``cyclic_error`` in the shape of the data: a delay periodic in the phase, a Fourier series of
harmonics 2 to 6 of the unambiguous range (a flexible member of the ``cyclic_error`` effect).

The catalogue's form holds only the correlation harmonics that alias into the first DFT bin of
N equally spaced samples (a depth error of period ``R / N``). A camera's wiggling has other
periods too: unequal sample steps and a reference wave that differs from the light's give
``R / 2`` and ``R / 3``, a band-limited driver bends the harmonics' share. This member fits the
delay itself as a function of the decoded phase ``phi``,

    delta(phi) = sum_{k = 2..6} c_k cos(k phi) + s_k sin(k phi),

ten parameters (the AIC counts ten). The first harmonic (period ``R``: a smooth bend over the
whole range, which a depth-dependent bias of any other cause also makes) is left out. Its
signature is the effect's: a depth error that follows the phase alone, the same at every pixel
of that depth, whatever its amplitude or place; the report names it ``cyclic_error``.
"""

from __future__ import annotations

import math

import torch

from ... import constants as K
from ...sim import CyclicError
from ..params import SCALE_DEPTH, ParamSpec
from .base import Term, depth_residuals, r4

__all__ = ["RANGE_HARMONICS", "CyclicErrorSeriesTerm"]

#: the harmonics of the range in the delay
RANGE_HARMONICS: tuple[int, ...] = (2, 3, 4, 5, 6)
_KEYS = tuple(f"cyclic_error_series.{p}{k}" for k in RANGE_HARMONICS for p in ("cos", "sin"))


class CyclicErrorSeriesTerm(Term):
    """Cosine and sine coefficients (m) of the delay's harmonics; started at the weighted
    least-squares fit of the depth residuals on the harmonics of the scene's phase."""

    name = "cyclic_error_series"
    signature = "cyclic_error"
    specs = tuple(ParamSpec(k, "lin", SCALE_DEPTH, "m") for k in _KEYS)
    enters = "chain"
    sim_name = "cyclic_error"
    axes = ("depth_mean|depth_mod", "depth_mean|depth")
    about = "a delay periodic in the phase of any shape (harmonics 2-6 of the range)"

    def simulator_term(self, v: dict, model):
        return CyclicError(
            harmonics=(),
            cos_terms=(),
            sin_terms=(),
            range_harmonics=RANGE_HARMONICS,
            range_cos=tuple(v[f"cyclic_error_series.cos{k}"] for k in RANGE_HARMONICS),
            range_sin=tuple(v[f"cyclic_error_series.sin{k}"] for k in RANGE_HARMONICS),
        )

    def initial_values(self, model, obs, ctx, pred) -> list[dict]:
        rd, wd = depth_residuals(obs, ctx, pred)
        if rd.numel() < 4 * len(_KEYS):
            return []
        f = float(model.camera.modulation_frequency)
        phi = obs.scene_depth[ctx.mask_d] * (4 * math.pi * f / K.SPEED_OF_LIGHT_AIR)
        basis = torch.stack([fn(k * phi) for k in RANGE_HARMONICS for fn in (torch.cos, torch.sin)])
        sw = torch.sqrt(wd.clamp_min(0))
        # weighted least squares with a small ridge (a scene that spans little of the range)
        a = (basis * sw) @ (basis * sw).T
        a = a + 1e-6 * torch.trace(a) / a.shape[0] * torch.eye(a.shape[0], dtype=a.dtype)
        coef = torch.linalg.solve(a, (basis * sw) @ (rd * sw))
        return [
            {k: float(c) for k, c in zip(_KEYS, coef, strict=True)},
            {k: 0.0 for k in _KEYS},
        ]

    def describe(self, model, obs, pred) -> dict:
        v = model.values
        term = self.simulator_term(v, model)
        phi = torch.linspace(0, 2 * math.pi, 257, dtype=torch.float64)[:-1]
        d = term.range_delay(phi)
        return {
            "peak_to_peak_mm": r4(float(d.max() - d.min()) * 1e3),
            "harmonics": list(RANGE_HARMONICS),
            "amplitudes_mm": [
                r4(
                    math.hypot(v[f"cyclic_error_series.cos{k}"], v[f"cyclic_error_series.sin{k}"])
                    * 1e3
                )
                for k in RANGE_HARMONICS
            ],
        }
