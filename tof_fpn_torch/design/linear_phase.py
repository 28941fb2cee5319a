r"""Linear-phase FIR design by the generalized Remez exchange, optionally with a fixed DC gain.

:func:`remez_linear_phase` turns a symmetric (type I or II) filter design with frequency-dependent
weight ``W`` and desired response ``D`` into the cosine-polynomial problem that
:func:`~tof_fpn_torch.design.remez.remez_cosine` solves.

A fixed response at ``w = 0`` (an exact constraint ``G(0) = c``)
-----------------------------------------------------------------
With ``x = cos w`` the cosine part is an algebraic polynomial ``P(x)`` of degree ``M`` and
``w = 0`` is ``x = 1``. Every polynomial with ``P(1) = c`` is ``P(x) = c + (1 - x) Q(x)`` with
``Q`` of degree ``M - 1`` (divide ``P - c`` by its root ``x = 1``), and conversely. The weighted
error becomes::

    W (P - D) = W (1 - x) (Q - (D - c) / (1 - x)) = W' (Q - D')
    W' = W (1 - cos w),      D' = (D - c) / (1 - cos w)

so the constrained minimax problem over ``P`` is the *unconstrained* minimax problem over ``Q``
with weight ``W'`` and desired ``D'``: the same exchange, one degree of freedom less, and its
alternation theorem (``M + 1`` alternating extrema) characterises the constrained optimum. ``W'``
vanishes at ``w = 0``, where the error is zero by construction, so that one point is left out of
the grid. (For a type II filter the cosine part is ``G(w) / cos(w / 2)``, equal to ``G`` at 0, so
the same ``c`` applies.) The optimum is checked against an independent linear programme with the
equality ``H(0) = 1`` in ``tests/test_design.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .remez import (
    RemezConvergenceError,
    RemezResult,
    _cosine_coefficients,
    make_grid,
    remez_cosine,
)

__all__ = ["cosine_to_taps", "remez_linear_phase"]

FreqFunction = Callable[[np.ndarray], np.ndarray]
#: grid points closer than this to ``w = 0`` are dropped under a DC constraint (``W' ~ w^2 / 2``)
_DC_GAP = 1e-9


def cosine_to_taps(a: np.ndarray) -> np.ndarray:
    """Symmetric impulse response of length ``2M+1`` whose zero-phase response is ``sum a_k cos kw``."""
    m = a.size - 1
    h = np.empty(2 * m + 1)
    h[m] = a[0]
    h[m + 1 :] = a[1:] / 2
    h[:m] = a[:0:-1] / 2
    return h


def _check_bands(bands) -> np.ndarray:
    bands_arr = np.asarray(bands, dtype=np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(bands_arr)):
        raise ValueError(f"bands must be finite, got {bands_arr.tolist()}")
    if np.any(bands_arr[:, 1] < bands_arr[:, 0]) or np.any(bands_arr[1:, 0] <= bands_arr[:-1, 1]):
        raise ValueError(f"bands must be ascending and non-overlapping, got {bands_arr.tolist()}")
    if bands_arr[0, 0] < 0 or bands_arr[-1, 1] > np.pi:
        raise ValueError(f"bands must lie in [0, pi], got {bands_arr.tolist()}")
    return bands_arr


def remez_linear_phase(
    numtaps: int,
    bands: Sequence[Sequence[float]] | np.ndarray,
    desired: FreqFunction,
    weight: FreqFunction,
    *,
    fixed_dc: float | None = None,
    grid_density: int = 8,
    maxiter: int = 100,
    tol: float = 1e-7,
) -> tuple[np.ndarray, RemezResult]:
    """Design a symmetric (type I or II) linear-phase FIR filter with frequency-dependent specs.

    Minimises ``max_{w in X} W(w) |G(w) - D(w)|`` where ``G(w)`` is the zero-phase response and
    ``X`` the union of ``bands`` (radians, within ``[0, pi]``), optionally subject to ``G(0) =
    fixed_dc`` exactly (see the module docstring).

    Args:
        numtaps: filter length; odd gives type I, even gives type II (which has a zero at ``pi``, so
            no band may reach ``pi``).
        bands: ``(K, 2)`` band edges in radians, ascending and non-overlapping.
        desired: vectorised ``D(w)``.
        weight: vectorised ``W(w) > 0``.
        fixed_dc: the exact value of ``G(0)``, or None (unconstrained). The first band must start
            at 0.
        grid_density: grid points per ``pi / (M + 1)`` of band width, ``M + 1`` the number of
            free coefficients.
        maxiter, tol: see :func:`~tof_fpn_torch.design.remez.remez_cosine`.

    Returns:
        ``(taps, result)``: ``taps`` of shape ``(numtaps,)`` (symmetric) and the exchange result for
        the cosine part (of ``Q`` under a DC constraint).
    """
    if not isinstance(numtaps, (int, np.integer)) or numtaps < 1:
        raise ValueError(f"numtaps must be an integer >= 1, got {numtaps!r}")
    bands_arr = _check_bands(bands)
    type2 = numtaps % 2 == 0
    if type2 and bands_arr[-1, 1] >= np.pi:
        raise ValueError("an even numtaps (type II) filter is zero at pi; bands must end below pi")
    degree = (numtaps - 2) // 2 if type2 else (numtaps - 1) // 2
    if fixed_dc is not None:
        if not np.isfinite(fixed_dc):
            raise ValueError(f"fixed_dc must be finite or None, got {fixed_dc!r}")
        if bands_arr[0, 0] != 0.0:
            raise ValueError(f"fixed_dc needs a band starting at 0, got {bands_arr.tolist()}")
        if degree == 0:  # nothing left to optimise: P is the constant itself
            return _constant(float(fixed_dc), type2, bands_arr, desired, weight)
    problem = _CosineProblem(bands_arr, desired, weight, fixed_dc, type2, degree)
    try:
        res = problem.exchange(grid_density, maxiter, tol)
    except RemezConvergenceError as exc:  # any stage: hand the last iterate to the caller
        if exc.coefficients is not None:
            exc.taps = problem.to_taps(exc.coefficients)
        raise
    return problem.to_taps(res.coefficients), res


def _constant(
    dc: float, type2: bool, bands: np.ndarray, desired: FreqFunction, weight: FreqFunction
) -> tuple[np.ndarray, RemezResult]:
    """The filter whose ``P`` is the constant ``dc`` (a DC constraint and no free coefficient),
    with its weighted error on a 512-point grid."""
    coeffs = np.array([dc])
    taps = cosine_to_taps(coeffs)
    taps = np.convolve(taps, [0.5, 0.5]) if type2 else taps
    omega, _ = make_grid(bands, 512)
    n = np.arange(taps.size) - (taps.size - 1) / 2
    g = np.cos(np.outer(omega, n)) @ taps
    err = float(np.max(np.abs(np.asarray(weight(omega)) * (g - desired(omega)))))
    return taps, RemezResult(coeffs, err, err, 0, omega[:1])


@dataclass
class _CosineProblem:
    """The cosine-polynomial problem of :func:`remez_linear_phase` (module docstring): the specs
    of ``P`` (type II: ``G = cos(w / 2) P``), of ``Q`` under a DC constraint
    (``P = c + (1 - cos w) Q``), and the taps from the solved coefficients."""

    bands: np.ndarray
    desired: FreqFunction
    weight: FreqFunction
    fixed_dc: float | None
    type2: bool
    degree: int

    @property
    def constrained(self) -> bool:
        return self.fixed_dc is not None

    @property
    def free(self) -> int:
        """Degree of the polynomial the exchange optimises (``Q``'s under a DC constraint)."""
        return self.degree - 1 if self.constrained else self.degree

    def specs(self, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = np.asarray(self.desired(omega), dtype=np.float64)
        w = np.asarray(self.weight(omega), dtype=np.float64)
        if self.type2:
            c = np.cos(omega / 2)
            d, w = d / c, w * c
        if self.constrained:
            one_minus_x = 1.0 - np.cos(omega)
            d, w = (d - self.fixed_dc) / one_minus_x, w * one_minus_x
        return d, w

    def grid(self, num: int) -> tuple[np.ndarray, np.ndarray]:
        omega, label = make_grid(self.bands, num)
        if self.constrained:
            keep = omega > _DC_GAP
            omega, label = omega[keep], label[keep]
        return omega, label

    def to_taps(self, coefficients: np.ndarray) -> np.ndarray:
        if self.constrained:  # P(w) = c + (1 - cos w) Q(w), as cosine coefficients of degree M
            q = coefficients
            dc = self.fixed_dc

            def p_of(w: np.ndarray) -> np.ndarray:
                return dc + (1.0 - np.cos(w)) * (np.cos(np.outer(w, np.arange(q.size))) @ q)

            coefficients = _cosine_coefficients(p_of, self.degree)
        taps = cosine_to_taps(coefficients)
        return np.convolve(taps, [0.5, 0.5]) if self.type2 else taps

    def exchange(self, grid_density: int, maxiter: int, tol: float) -> RemezResult:
        free = self.free
        # Stage 1: the exchange on a uniform grid of each band.
        omega, label = self.grid(grid_density * (free + 1))
        res = remez_cosine(free, omega, *self.specs(omega), label, maxiter=maxiter, tol=tol)
        # Stages 2 and 3: a 4x denser grid plus a fine local grid (33 points across two of its
        # steps) around every extremal frequency, exchanging again from the converged reference.
        # The dense grid catches lobes the coarse one missed (they crowd near band edges, where W
        # varies fast); the local grids pin the extrema to 1/16 of a step, so the levelled error
        # matches the true maximum to ~1e-4 (checked again by the caller on an independent grid).
        omega, label = self.grid(4 * grid_density * (free + 1))
        step = np.diff(omega)[label[1:] == label[:-1]].max(initial=0.0)  # within bands only
        for _ in range(2):
            local = (res.extremal_frequencies[:, None] + np.linspace(-step, step, 33)).ravel()
            idx = np.searchsorted(self.bands[:, 0], local, side="right") - 1
            inside = (idx >= 0) & (local <= self.bands[np.clip(idx, 0, None), 1])
            if self.constrained:
                inside &= local > _DC_GAP
            fine = np.unique(np.concatenate([omega, local[inside]]))
            fine_label = np.searchsorted(self.bands[:, 0], fine, side="right") - 1
            res = remez_cosine(
                free,
                fine,
                *self.specs(fine),
                fine_label,
                initial=res.extremal_frequencies,
                maxiter=maxiter,
                tol=tol,
            )
        return res
