"""``cyclic_error``: a non-sinusoidal correlation (its harmonics alias into the decoded phase),
or any delay periodic in the phase."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .camera import _as_float
from .phasor import _phase_per_metre, fundamental, rotate_fundamental
from .terms import SimState, Term, _num

__all__ = ["CyclicError"]


@dataclass
class CyclicError(Term):
    """Non-sinusoidal correlation ("wiggling"): harmonics of the fundamental.

    ``R_n = B + A [cos(psi_n) + sum_h alpha_h cos(h psi_n) + beta_h sin(h psi_n)]`` with
    ``psi_n = phi + 2 pi n / N``. Harmonic ``h`` aliases into the decoded phase (for N = 4 the
    3rd and 5th give a depth error of period ``c_L / (8 f)``). Args: ``harmonics`` (ints >= 2),
    ``cos_terms`` alpha_h and ``sin_terms`` beta_h relative to the fundamental.

    A camera's wiggling has its own shape (unequal sample steps, a reference wave that is not the
    light's, a band-limited driver): with ``range_harmonics`` (ints >= 1) the decoded phase
    ``phi`` is moreover delayed by ``delta(phi) = sum_k c_k cos(k phi) + s_k sin(k phi)`` (m),
    ``range_cos`` c_k and ``range_sin`` s_k: any delay periodic in the phase.
    """

    harmonics: tuple = (3, 5)
    cos_terms: tuple = (0.0, 0.0)
    sin_terms: tuple = (0.0, 0.0)
    range_harmonics: tuple = ()
    range_cos: tuple = ()
    range_sin: tuple = ()
    name: str = field(default="cyclic_error", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> CyclicError:
        k = len(self.harmonics)
        if len(self.cos_terms) != k or len(self.sin_terms) != k:
            raise ValueError("CyclicError: one cos_terms and sin_terms entry per harmonic")
        for h in self.harmonics:
            if isinstance(h, bool) or not isinstance(h, int) or h < 2:
                raise ValueError(f"CyclicError.harmonics must be ints >= 2, got {self.harmonics}")
        for v in (*self.cos_terms, *self.sin_terms):
            _as_float(v, "CyclicError terms")
        k = len(self.range_harmonics)
        if len(self.range_cos) != k or len(self.range_sin) != k:
            raise ValueError(
                "CyclicError: one range_cos and range_sin entry per range harmonic, got "
                f"{k}, {len(self.range_cos)} and {len(self.range_sin)}"
            )
        for h in self.range_harmonics:
            if isinstance(h, bool) or not isinstance(h, int) or h < 1:
                raise ValueError(
                    f"CyclicError.range_harmonics must be ints >= 1, got {self.range_harmonics}"
                )
        for v in (*self.range_cos, *self.range_sin):
            _as_float(v, "CyclicError range terms")
        return self

    def range_delay(self, phase: torch.Tensor) -> torch.Tensor:
        """The delay (m) periodic in the decoded ``phase`` (rad), 0 without range harmonics."""
        out = torch.zeros_like(phase)
        for k, a, b in zip(self.range_harmonics, self.range_cos, self.range_sin, strict=True):
            out = (
                out + _num(a, phase) * torch.cos(k * phase) + _num(b, phase) * torch.sin(k * phase)
            )
        return out

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        n = s.shape[1]
        xr, xi = fundamental(s)
        mag = torch.sqrt(xr * xr + xi * xi + 1e-12)
        amp = mag * (2.0 / n)
        theta = torch.arange(n, dtype=torch.float64, device=s.device) * (2 * math.pi / n)
        ur, ui = (xr / mag), (xi / mag)  # e^{j phi}
        add = torch.zeros_like(s)
        for h, a, b in zip(self.harmonics, self.cos_terms, self.sin_terms, strict=True):
            # e^{j h psi_n} = e^{j h phi} e^{j h theta_n}
            pr, pi_ = torch.ones_like(ur), torch.zeros_like(ui)
            for _ in range(h):
                pr, pi_ = pr * ur - pi_ * ui, pr * ui + pi_ * ur
            ct = torch.cos(h * theta).to(s.dtype).view(1, n, 1, 1)
            st = torch.sin(h * theta).to(s.dtype).view(1, n, 1, 1)
            cos_h = pr * ct - pi_ * st
            sin_h = pr * st + pi_ * ct
            add = add + _num(a, s) * cos_h + _num(b, s) * sin_h
        s = s + amp * add
        if self.range_harmonics:
            xr, xi = fundamental(s)
            delay = self.range_delay(torch.atan2(xi, xr))
            s = rotate_fundamental(s, delay * _phase_per_metre(state.camera))
        state.samples = s
        return state
