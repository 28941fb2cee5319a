"""Offline design of linear-phase notch FIR filters for FPN suppression (NumPy only).

Implements Sec. III of M. Georgiev, R. Bregovic and A. Gotchev, "Fixed-pattern noise suppression in
low-sensing environment of Time-of-Flight devices", IEEE SAS 2015 (DOI 10.1109/SAS.2015.7133633).

The filter is ``H(z) = A(z) G(z)`` (eq. 4). ``A(z)`` holds fixed zeros at the FPN frequencies: for
each notch ``w0`` in ``(0, pi)`` the pair ``1 - 2 cos(w0) z^-1 + z^-2`` (``A1 = 1 + z^-1 + z^-2`` for
``w0 = 2pi/3``), and for ``w0 = pi`` the single zero ``A2 = 1 + z^-1``. ``G`` is a symmetric FIR of
order ``N_G = N - deg A`` designed by a Remez exchange (:mod:`tof_fpn_torch.design.remez`).

Derivation of the weight and desired response (the seed's eq. 7 is garbled)
-----------------------------------------------------------------------------
Write every linear-phase factor through its real, *signed* zero-phase response
(``F(e^jw) = e^{-j w n_F / 2} F(w)``)::

    A1(w) = 1 + 2 cos(w)          # > 0 on [0, 2pi/3), < 0 on (2pi/3, pi]
    A2(w) = 2 cos(w / 2)          # >= 0 on [0, pi]
    A(w)  = prod over notches (2 cos w - 2 cos w0)  [x 2 cos(w/2) if pi is a notch]

so ``H(w) = A(w) G(w)``. The design goal is ``min_g max_{w in X} |H(w) - 1|`` (passband ripple
``delta`` around a gain of +1 in every band, eq. 3 and the problem below eq. 3). Since ``A(w) != 0``
on ``X`` (the notches lie in the transition bands),::

    H(w) - 1 = A(w) G(w) - 1 = |A(w)| * sign(A(w)) * (G(w) - 1/A(w))
    |H(w) - 1| = |A(w)| * |G(w) - 1/A(w)|

which is exactly the Remez error ``E(w) = W(w) [G(w) - D(w)]`` (eq. 6) in absolute value with::

    W(w) = |A(w)|          D(w) = 1 / A(w)          (signed: D < 0 where A1(w) < 0)

The extracted text prints ``W = 1/|A1 A2|`` and ``D = |A1 A2|``: inverted, and with the absolute value
on ``D`` the second band (``2pi/3 < w < pi``, where ``A1 < 0``) would be driven to ``H = -1``
(an inversion of the high frequencies) or, for ``|H|`` specs, be inconsistent with a real ``G``.
``tests/test_design.py`` checks the form above against an independent linear programme.

Parities: for even ``N`` with the default notches ``N_G`` is odd, ``G`` is type II and carries
its own zero at ``pi`` (a double zero of ``H`` there, the paper's "two zeros at pi"); its zero-phase
response is ``cos(w/2) P(w)`` and the Remez runs on ``P`` with ``W cos(w/2)`` and ``D / cos(w/2)``.
For odd ``N`` the taps have even length and the filter delays by ``N / 2``, a half-sample
(:attr:`FPNDesign.half_sample_delay`).

Unit DC gain (default; not in the paper)
----------------------------------------
The paper's minimax design puts a ripple extremum at ``w = 0``, so depth comes out scaled by
``H(0) = 1 +- delta`` (0.967 for ``{20, 0.14}``: a 3.3 % depth bias wherever the filtered depth is
used). ``unit_dc=True`` adds the exact constraint ``H(0) = 1``, i.e. ``G(0) = 1 / A(0)``, and
solves the constrained minimax problem (:mod:`tof_fpn_torch.design.linear_phase`: ``G = c + (1 -
cos w) Q``, an unconstrained exchange over ``Q``); its optimality is checked against the linear
programme with the same equality in ``tests/test_design_dc.py``. ``unit_dc=False`` is the paper's
unconstrained design (Table I's paper-exact column).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..constants import DEFAULT_NOTCHES
from .bands import check_notches, fpn_bands
from .linear_phase import remez_linear_phase
from .remez import RemezConvergenceError
from .response import fixed_zero_response, fixed_zero_taps, passband_ripple

__all__ = ["MAX_ORDER", "RIPPLE_FLOOR", "FPNDesign", "design_fpn", "design_fpn_filter"]

#: Largest order :func:`design_fpn` accepts. Above order ~140 every design of the default notches
#: already lies below the float64 floor (:data:`RIPPLE_FLOOR`, -100 dB) and the optimised factor
#: ``G`` stays at order <= 133; a larger order only pads zero taps, while the exchange's memory and
#: time grow as the order squared (measured: order 2000 takes 1.6 s and 170 MB, order 10 000 28 s,
#: order 100 000 runs out of memory). 1024 taps is also wider than the frames of ToF cameras.
MAX_ORDER = 1024

#: Ripple (-100 dB) below which a design is not held to the 0.5 % optimality check. Wide
#: transition bands at high orders make ``G`` a high-degree polynomial extrapolated across the gaps
#: between bands; evaluating it amplifies rounding by many orders of magnitude, and optima far below
#: -100 dB get lost in it (the exchange stalls). There :func:`design_fpn` lowers the order of ``G``
#: (zero-padding it back, same delay) to the highest one that verifies with a ripple under this
#: floor, and reports it in :attr:`FPNDesign.g_order`: at most -100 dB of ripple is given away.
RIPPLE_FLOOR = 1e-5


@dataclass(frozen=True)
class FPNDesign:
    """A designed FPN notch filter and its figures of merit.

    Attributes:
        taps: ``h[0..order]``, float64, symmetric.
        order: ``N``.
        rho: transition half-width parameter (eq. 8).
        notches: notch frequencies (radians), ascending.
        bands: ``(K, 2)`` passbands.
        band_ripples: ``max |H(w) - 1|`` per band (dense grid).
        ripple: the largest of ``band_ripples`` (linear ``delta``).
        notch_gains: ``|H(e^{j w0})|`` per notch (zero up to rounding).
        iterations: Remez iterations of the last stage (0: a stalled iterate accepted under the
            floor, see :data:`RIPPLE_FLOOR`).
        g_order: order of ``G`` actually optimised: ``order - deg A`` unless the full problem was
            below float64 precision (see :data:`RIPPLE_FLOOR`), then lower and zero-padded.
        band_weights: relative ripple weights per band used in the design.
        unit_dc: designed with the exact constraint ``H(0) = 1`` (:attr:`dc_gain`).
    """

    taps: np.ndarray
    order: int
    rho: float
    notches: tuple[float, ...]
    bands: np.ndarray
    band_ripples: np.ndarray
    ripple: float
    notch_gains: np.ndarray
    iterations: int
    g_order: int
    band_weights: tuple[float, ...] = field(default=())
    unit_dc: bool = True

    @property
    def dc_gain(self) -> float:
        """``H(0) = sum(taps)``: exactly 1 (to rounding) for ``unit_dc`` designs."""
        return float(np.sum(self.taps))

    @property
    def ripple_db(self) -> float:
        """``20 log10(delta)``."""
        return 20.0 * math.log10(self.ripple)

    @property
    def group_delay(self) -> float:
        """Constant group delay ``N / 2`` in samples."""
        return self.order / 2.0

    @property
    def half_sample_delay(self) -> bool:
        """True for odd orders: the output sits half a sample off the input grid."""
        return self.order % 2 == 1

    @property
    def notch_depths_db(self) -> np.ndarray:
        """``20 log10 |H(e^{j w0})|`` per notch (floored at -400 dB)."""
        return 20.0 * np.log10(np.maximum(self.notch_gains, 1e-20))

    def summary(self) -> dict:
        """JSON-friendly report (used by the CLI)."""
        return {
            "order": self.order,
            "rho": self.rho,
            "notches": list(self.notches),
            "bands": self.bands.tolist(),
            "ripple": self.ripple,
            "ripple_db": self.ripple_db,
            "band_ripples": self.band_ripples.tolist(),
            "band_weights": list(self.band_weights),
            "group_delay": self.group_delay,
            "half_sample_delay": self.half_sample_delay,
            "notch_gains": self.notch_gains.tolist(),
            "notch_depths_db": self.notch_depths_db.tolist(),
            "iterations": self.iterations,
            "g_order": self.g_order,
            "unit_dc": self.unit_dc,
            "dc_gain": self.dc_gain,
            "taps": self.taps.tolist(),
        }


def design_fpn(
    order: int,
    rho: float,
    *,
    notches: Sequence[float] = DEFAULT_NOTCHES,
    band_weights: Sequence[float] | None = None,
    unit_dc: bool = True,
    grid_density: int = 8,
    maxiter: int = 100,
) -> FPNDesign:
    """Design ``H(z) = A(z) G(z)`` minimising ``max_{w in X} |H(w) - 1|`` (Georgiev et al. 2015).

    Args:
        order: filter order ``N`` (``N + 1`` taps), at least ``deg A`` (3 for the default notches).
            Both parities work: even orders add a second zero at ``pi``; odd orders delay by a
            half-sample.
        rho: transition half-width as a fraction of ``pi`` (eq. 8); ``(0, 1/6]`` for the defaults.
        notches: FPN frequencies in ``(0, pi]`` (radians per sample), default ``(2pi/3, pi)``.
        band_weights: optional relative weight per passband (the paper's "future work"): band ``k``
            gets ripple ``~ delta / band_weights[k]``. Default: equal ripple.
        unit_dc: constrain ``H(0) = 1`` exactly (default; no depth bias); False gives the
            paper's unconstrained minimax design, whose ``H(0)`` is off by up to the ripple.
        grid_density: Remez grid points per extremal spacing (default 8; a second stage refines
            the grid around the extremal frequencies).
        maxiter: Remez iterations before :class:`RemezConvergenceError`.

    Returns:
        :class:`FPNDesign`.

    Raises:
        ValueError: an argument is invalid (the message names it, its value and what is allowed).
        RemezConvergenceError: the exchange did not converge (the message suggests a change).
    """
    order = _check_arguments(order, grid_density, maxiter, unit_dc)
    w = check_notches(notches)
    bands = fpn_bands(rho, w)
    a_taps = fixed_zero_taps(w)
    n_g = _g_order(order, w, a_taps, bands)
    bw = _band_weights(band_weights, bands)
    problem = _Problem(order, rho, w, bands, bw, a_taps, n_g, unit_dc, grid_density, maxiter)
    found, final = problem.attempt(0)
    if found is None:
        found = _highest_verified_order(problem.attempt, n_g // 2)
    if found is None:
        raise problem.errors[0]
    return _finish(problem, *found)


def _check_arguments(order, grid_density, maxiter, unit_dc) -> int:
    """``order`` as an int; ValueError for a bad order, grid density, iteration count or flag."""
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
        raise ValueError(f"order must be an integer, got {order!r}")
    order = int(order)
    if order > MAX_ORDER:
        raise ValueError(
            f"order={order} is too large: order must be <= {MAX_ORDER} (MAX_ORDER). Above ~140 "
            "every design is below float64 precision (ripple < -100 dB) and extra order only adds "
            "zero taps, while design time and memory grow as the order squared"
        )
    if isinstance(grid_density, bool) or not isinstance(grid_density, (int, np.integer)):
        raise ValueError(f"grid_density must be an integer >= 4, got {grid_density!r}")
    if grid_density < 4:
        raise ValueError(f"grid_density must be an integer >= 4, got {grid_density!r}")
    if isinstance(maxiter, bool) or not isinstance(maxiter, (int, np.integer)) or maxiter < 1:
        raise ValueError(f"maxiter must be an integer >= 1, got {maxiter!r}")
    if not isinstance(unit_dc, (bool, np.bool_)):
        raise ValueError(f"unit_dc must be a bool, got {unit_dc!r}")
    return order


def _g_order(order: int, w: np.ndarray, a_taps: np.ndarray, bands: np.ndarray) -> int:
    """The order ``N_G = N - deg A`` of ``G``; ValueError where ``order`` cannot hold ``A`` or
    leaves ``G`` a forced zero at pi inside a passband."""
    n_fixed = a_taps.size - 1
    if order < n_fixed:
        raise ValueError(
            f"order={order} is too small for notches {w.tolist()}: their fixed zeros alone have "
            f"order {n_fixed}; order must be >= {n_fixed}"
        )
    n_g = order - n_fixed
    if n_g % 2 == 1 and bands[-1, 1] >= np.pi:
        raise ValueError(
            f"order={order} leaves G(z) of odd order {n_g}, which forces a zero at pi, but the "
            f"passband reaches pi (last notch {w[-1]:.6g} < pi); use order {order - 1} or {order + 1}"
        )
    return n_g


def _band_weights(band_weights, bands: np.ndarray) -> np.ndarray:
    """The relative ripple weight of each passband (ones by default); ValueError if bad."""
    if band_weights is None:
        return np.ones(bands.shape[0])
    bw = np.asarray(band_weights, dtype=np.float64).reshape(-1)
    if bw.size != bands.shape[0] or not np.all(np.isfinite(bw)) or np.any(bw <= 0):
        raise ValueError(
            f"band_weights must be {bands.shape[0]} finite positive numbers (one per passband "
            f"{bands.tolist()}), got {list(band_weights)!r}"
        )
    return bw


@dataclass
class _Problem:
    """The minimax problem of one design (module docstring): weight ``|A| band_weight``, desired
    response ``1 / A``, and the attempts at it (the errors of the failed ones in ``errors``)."""

    order: int
    rho: float
    w: np.ndarray
    bands: np.ndarray
    bw: np.ndarray
    a_taps: np.ndarray
    n_g: int
    unit_dc: bool
    grid_density: int
    maxiter: int
    errors: list[RemezConvergenceError] = field(default_factory=list)

    def band_weight(self, omega: np.ndarray) -> np.ndarray:
        idx = np.searchsorted(self.bands[:, 0], omega, side="right") - 1
        return self.bw[np.clip(idx, 0, self.bw.size - 1)]

    def desired(self, omega: np.ndarray) -> np.ndarray:
        return 1.0 / fixed_zero_response(omega, self.w)

    def weight(self, omega: np.ndarray) -> np.ndarray:
        return np.abs(fixed_zero_response(omega, self.w)) * self.band_weight(omega)

    def attempt(self, drop: int):
        """Design G of order ``n_g - 2 drop``, zero-padded back to ``n_g``.

        Returns ``(found, final)``: ``found`` is ``(taps, result, band_ripples, drop)`` when it
        verifies on the dense grid (and, for ``drop > 0``, lies under the floor); ``final`` says
        that a verified lower-order design already misses the floor, so lower ones will too.
        """
        # G(0) = 1 / A(0) <=> H(0) = 1
        dc = float(self.desired(np.zeros(1))[0]) if self.unit_dc else None
        try:
            g_taps, res = remez_linear_phase(
                self.n_g + 1 - 2 * drop,
                self.bands,
                self.desired,
                self.weight,
                fixed_dc=dc,
                grid_density=self.grid_density,
                maxiter=self.maxiter,
            )
            levelled = res.delta
        except RemezConvergenceError as exc:
            self.errors.append(exc)
            if exc.taps is None:
                return None, False
            # A stalled iterate already under the floor is still a fine filter (checked below).
            g_taps, res, levelled = exc.taps, None, 0.0
        taps = np.convolve(self.a_taps, np.pad(g_taps, drop))
        band_ripples = passband_ripple(taps, self.bands) / self.bw  # weighted, as the exchange saw
        ripple = band_ripples.max()
        if ripple <= max(1.005 * levelled, RIPPLE_FLOOR) and (drop == 0 or ripple <= RIPPLE_FLOOR):
            return (taps, res, band_ripples, drop), False
        if res is not None:
            self.errors.append(
                RemezConvergenceError(
                    f"order={self.order}, rho={self.rho}: the exchange levelled the error at "
                    f"{levelled:.3e} on its grid but the dense-grid ripple is {ripple:.3e}; use a "
                    "larger grid_density"
                )
            )
        # A trustworthy (levelled = dense) design above the floor: lower orders only do worse.
        return None, drop > 0 and res is not None and ripple <= 1.005 * levelled


def _finish(problem: _Problem, taps, res, band_ripples, drop) -> FPNDesign:
    """The :class:`FPNDesign` of a verified attempt: taps made exactly symmetric (and of unit sum
    for ``unit_dc``), the figures of merit."""
    bw, w = problem.bw, problem.w
    band_ripples = band_ripples * bw
    taps = 0.5 * (taps + taps[::-1])  # exactly symmetric (the convolutions round unevenly)
    if problem.unit_dc:
        taps = taps / taps.sum()  # H(0) = 1 to the last bit (it is 1 to ~1e-15 already)
    notch_gains = np.abs(np.exp(-1j * np.outer(w, np.arange(taps.size))) @ taps)
    return FPNDesign(
        taps=taps,
        order=problem.order,
        rho=float(problem.rho),
        notches=tuple(float(v) for v in w),
        bands=problem.bands,
        band_ripples=band_ripples,
        ripple=float(band_ripples.max()),
        notch_gains=notch_gains,
        iterations=res.iterations if res is not None else 0,
        g_order=problem.n_g - 2 * drop,
        band_weights=tuple(float(v) for v in bw),
        unit_dc=bool(problem.unit_dc),
    )


def _highest_verified_order(attempt, max_drop: int):
    """Smallest ``drop`` in ``1..max_drop`` whose design verifies under the floor, or None.

    In practice the outcomes are ordered: high orders of G are lost in rounding (no design), then a
    window verifies under the floor, then lower orders verify above it (``final``). Bisection finds
    the first order that is not lost; should the outcomes not be ordered, a linear scan follows.
    """
    lo, hi, best = 0, max_drop + 1, None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        found, final = attempt(mid)
        if found is None and not final:
            lo = mid
        else:
            hi, best = mid, found
    if best is not None:
        return best
    for drop in range(1, max_drop + 1):
        found, final = attempt(drop)
        if found is not None or final:
            return found
    return None


def design_fpn_filter(order: int, rho: float, **kwargs) -> np.ndarray:
    """Exactly ``design_fpn(order, rho, **kwargs).taps``, kept for the public API.

    No parameters or defaults of its own: ``kwargs`` are :func:`design_fpn`'s (``notches``,
    ``band_weights``, ``unit_dc``, ``grid_density``, ``maxiter``), documented and checked there;
    its :class:`FPNDesign` adds the figures of merit. Run-time modules: ``build.filter_from_design``.

    Example:
        >>> h = design_fpn_filter(20, 0.14)
        >>> h.shape
        (21,)
    """
    return design_fpn(order, rho, **kwargs).taps
