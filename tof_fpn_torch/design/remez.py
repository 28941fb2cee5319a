"""Generalized Remez exchange for linear-phase FIR filters (offline, NumPy only).

``scipy.signal.remez`` accepts one constant desired value and one constant weight per band. The FPN
notch design of Georgiev, Bregovic & Gotchev (IEEE SAS 2015, Sec. III-B) needs both to vary with
frequency (``W(w) = |A(w)|``, ``D(w) = 1/A(w)``, see :mod:`tof_fpn_torch.design`), so this module
implements the Parks-McClellan exchange for that general case [PM72]_:

* the zero-phase response of a type I filter (odd length ``2M+1``) is a cosine polynomial
  ``P(w) = sum_k a_k cos(k w)``, i.e. an algebraic polynomial of degree ``M`` in ``x = cos w``;
* a type II filter (even length ``2M+2``) has zero-phase response ``cos(w/2) P(w)``; it is reduced
  to the type I case with ``W'(w) = W(w) cos(w/2)`` and ``D'(w) = D(w) / cos(w/2)``;
* the Chebyshev problem ``min max_{w in X} W(w) |P(w) - D(w)|`` over a dense grid of the union of
  bands ``X`` is solved by the multiple exchange: on a reference set of ``M + 2`` frequencies the
  levelled error ``delta`` follows in closed form from barycentric weights, ``P`` is interpolated
  with the barycentric Lagrange formula [BT04]_, and the reference is replaced by the alternating
  extrema of the new error until the extrema equal ``|delta|`` to a relative tolerance.

.. [PM72] T. W. Parks and J. H. McClellan, "Chebyshev approximation for nonrecursive digital filters
   with linear phase," IEEE Trans. Circuit Theory 19(2), 1972.
.. [BT04] J.-P. Berrut and L. N. Trefethen, "Barycentric Lagrange interpolation," SIAM Review 46(3),
   2004.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["RemezConvergenceError", "RemezResult", "make_grid", "remez_cosine"]

FreqFunction = Callable[[np.ndarray], np.ndarray]


class RemezConvergenceError(RuntimeError):
    """Raised when the exchange does not level the error within ``maxiter`` iterations.

    Attributes:
        taps: the last iterate's filter (from :func:`remez_linear_phase`), or None. Not optimal;
            a caller may still verify it independently (see :func:`tof_fpn_torch.design.design_fpn`).
    """

    def __init__(self, message: str, taps: np.ndarray | None = None) -> None:
        super().__init__(message)
        self.taps = taps
        self.coefficients: np.ndarray | None = None


@dataclass(frozen=True)
class RemezResult:
    """Outcome of :func:`remez_cosine`.

    Attributes:
        coefficients: ``a_k`` of ``P(w) = sum_k a_k cos(k w)``, shape ``(M + 1,)``.
        delta: levelled weighted error ``|delta|`` on the final reference set.
        max_error: maximum weighted error on the design grid (equals ``delta`` at convergence).
        iterations: exchange iterations used.
        extremal_frequencies: the final reference set (radians), shape ``(M + 2,)``.
    """

    coefficients: np.ndarray
    delta: float
    max_error: float
    iterations: int
    extremal_frequencies: np.ndarray


def make_grid(bands: np.ndarray, num_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Dense grid over a union of bands, ``num_points`` spread in proportion to band widths.

    Every band gets at least its two edges (one point for a degenerate band ``[a, a]``).

    Returns:
        ``(omega, band_index)``, both of shape ``(G,)``, ``omega`` ascending.
    """
    widths = bands[:, 1] - bands[:, 0]
    total = float(widths.sum())
    grids, labels = [], []
    for i, (lo, hi) in enumerate(bands):
        if hi - lo <= 1e-9:
            pts = np.array([lo])
        else:
            n = max(2, int(np.ceil(num_points * (hi - lo) / total)) + 1)
            pts = np.linspace(lo, hi, n)
        grids.append(pts)
        labels.append(np.full(pts.shape, i))
    return np.concatenate(grids), np.concatenate(labels)


def _barycentric_weights(x: np.ndarray) -> np.ndarray:
    """``b_k = 1 / prod_{j != k} (x_k - x_j)``, scaled to ``max |b_k| = 1`` (only ratios matter).

    Computed in the log domain: for clustered nodes the plain products under- or overflow.
    """
    diff = x[:, None] - x[None, :]
    np.fill_diagonal(diff, 1.0)
    sign = np.prod(np.sign(diff), axis=1)
    log_mag = -np.sum(np.log(np.abs(diff)), axis=1)
    return sign * np.exp(log_mag - log_mag.max())


def _local_extrema(err: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Indices where ``|err|`` peaks within its band and sign lobe (band edges included)."""
    n = err.size
    left = np.empty(n, dtype=bool)
    right = np.empty(n, dtype=bool)
    same_left = np.zeros(n, dtype=bool)
    same_left[1:] = band[1:] == band[:-1]
    same_right = np.zeros(n, dtype=bool)
    same_right[:-1] = band[:-1] == band[1:]
    a = np.abs(err)
    flip = np.sign(err[1:]) != np.sign(err[:-1])  # a zero crossing bounds a lobe like an edge
    left[0] = True
    left[1:] = ~same_left[1:] | flip | (a[1:] >= a[:-1])
    right[-1] = True
    right[:-1] = ~same_right[:-1] | flip | (a[:-1] > a[1:])
    return np.flatnonzero(left & right & (a > 0))


def _select_alternating(idx: np.ndarray, err: np.ndarray, count: int) -> np.ndarray | None:
    """Reduce candidate extrema to ``count`` indices with alternating error signs.

    Runs of equal sign keep their largest member; then the smallest extremum goes with its smaller
    neighbour (or, when one too many or at an end, the smaller end goes) until ``count`` remain;
    either way the alternation survives.
    """
    if idx.size == 0:
        return None
    e = err[idx]
    sign = np.sign(e)
    run_start = np.ones(idx.size, dtype=bool)
    run_start[1:] = sign[1:] != sign[:-1]
    run_id = np.cumsum(run_start) - 1
    order = np.lexsort((-np.abs(e), run_id))  # by run, largest |e| first within a run
    first_of_run = np.ones(order.size, dtype=bool)
    first_of_run[1:] = run_id[order][1:] != run_id[order][:-1]
    keep = np.sort(idx[order[first_of_run]])
    if keep.size < count:
        return None
    keep = list(keep)
    while len(keep) > count:
        mag = np.abs(err[keep])
        k = int(np.argmin(mag))
        if len(keep) - count == 1 or k in (0, len(keep) - 1):
            # One too many (or the smallest is an end): drop the smaller end.
            del keep[0 if mag[0] < mag[-1] else -1]
        else:
            # Drop the smallest and its smaller neighbour: the alternation survives.
            j = k - 1 if mag[k - 1] < mag[k + 1] else k + 1
            del keep[max(j, k)], keep[min(j, k)]
    return np.asarray(keep)


def remez_cosine(
    degree: int,
    omega: np.ndarray,
    desired: np.ndarray,
    weight: np.ndarray,
    band: np.ndarray | None = None,
    *,
    initial: np.ndarray | None = None,
    maxiter: int = 100,
    tol: float = 1e-7,
) -> RemezResult:
    """Weighted Chebyshev approximation by a cosine polynomial on a grid (the Remez exchange).

    Minimises ``max_i weight[i] * |P(omega[i]) - desired[i]|`` over ``P(w) = sum_{k<=degree} a_k
    cos(k w)``.

    Args:
        degree: ``M >= 0``, the highest cosine harmonic.
        omega: ascending grid frequencies in ``[0, pi]``, shape ``(G,)`` with ``G >= M + 2``.
        desired: ``D`` on the grid, shape ``(G,)``.
        weight: positive ``W`` on the grid, shape ``(G,)``.
        band: integer band label of each grid point (extrema are searched within bands); default one.
        initial: optional starting reference, ``M + 2`` frequencies (snapped to the grid).
        maxiter: exchange iterations before :class:`RemezConvergenceError`.
        tol: convergence when ``(max|E| - |delta|) <= tol * max|E|``.
    """
    omega = np.asarray(omega, dtype=np.float64)
    desired = np.asarray(desired, dtype=np.float64)
    weight = np.asarray(weight, dtype=np.float64)
    band = np.zeros(omega.shape, dtype=np.int64) if band is None else np.asarray(band)
    n_ref = degree + 2
    _check_grid(omega, desired, weight, n_ref, degree)
    x_grid = np.cos(omega)
    ref = _start_reference(omega, band, initial, n_ref)
    alt = (-1.0) ** np.arange(n_ref)
    delta = 0.0
    max_err = np.inf
    error: RemezConvergenceError | None = None
    for it in range(1, maxiter + 1):
        delta, xi, ci, bi = _levelled(x_grid[ref], desired[ref], weight[ref], alt)
        p = _barycentric_eval(x_grid, xi, ci, bi)
        err = weight * (p - desired)
        max_err = float(np.max(np.abs(err)))
        new_ref = _select_alternating(_local_extrema(err, band), err, n_ref)
        if max_err - abs(delta) <= tol * max_err:
            break
        if new_ref is None or np.array_equal(new_ref, ref):
            # No further exchange possible on this grid: the reference is optimal for the grid.
            if new_ref is not None and max_err - abs(delta) <= 1e-6 * max_err:
                break
            error = RemezConvergenceError(
                f"Remez exchange stalled at iteration {it}: levelled error {abs(delta):.3e} but "
                f"max error {max_err:.3e} on the grid. Try a denser grid (grid_density), a lower "
                "order or wider transition bands."
            )
            break
        ref = new_ref
    else:
        error = RemezConvergenceError(
            f"Remez exchange did not converge in {maxiter} iterations (levelled error "
            f"{abs(delta):.3e}, max error {max_err:.3e}). Try a lower order, wider transition "
            "bands (larger rho) or a larger maxiter."
        )
    coeffs = _cosine_coefficients(lambda w: _barycentric_eval(np.cos(w), xi, ci, bi), degree)
    if error is not None:
        error.coefficients = coeffs
        raise error
    return RemezResult(coeffs, abs(delta), max_err, it, omega[ref])


def _check_grid(
    omega: np.ndarray, desired: np.ndarray, weight: np.ndarray, n_ref: int, degree: int
) -> None:
    if omega.size < n_ref or np.unique(omega).size != omega.size:
        raise ValueError(
            f"grid has {omega.size} points (must be distinct); degree {degree} needs >= {n_ref}"
        )
    if not (np.all(np.isfinite(desired)) and np.all(np.isfinite(weight)) and np.all(weight > 0)):
        raise ValueError("desired must be finite and weight finite and > 0 on the whole grid")


def _start_reference(
    omega: np.ndarray, band: np.ndarray, initial: np.ndarray | None, n_ref: int
) -> np.ndarray:
    """The starting reference: ``initial`` snapped to the grid when it gives ``n_ref`` distinct
    points, else :func:`_initial_reference`."""
    if initial is not None and np.size(initial) == n_ref:
        ref = np.unique(np.abs(omega[None, :] - np.asarray(initial)[:, None]).argmin(axis=1))
        if ref.size == n_ref:
            return ref
    return _initial_reference(omega, band, n_ref)


def _levelled(
    x: np.ndarray, d_ref: np.ndarray, w_ref: np.ndarray, alt: np.ndarray
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """``(delta, xi, ci, bi)``: the levelled error of the reference ``x = cos(omega_ref)`` and the
    barycentric interpolant of ``P`` (nodes ``xi``, values ``ci``, weights ``bi``)."""
    n_ref = x.size
    b = _barycentric_weights(x)
    delta = float(np.dot(b, d_ref) / np.dot(b, alt / w_ref))
    # P interpolates C_k = D_k - (-1)^k delta / W_k at every reference point; any M+1 of them
    # determine it. Leave out an interior one: extrapolating to an end point (e.g. a narrow
    # band far from the others) amplifies rounding errors enormously.
    sub = np.arange(n_ref) != n_ref // 2
    xi = x[sub]
    ci = (d_ref - alt * delta / w_ref)[sub]
    return delta, xi, ci, _barycentric_weights(xi)


def _initial_reference(omega: np.ndarray, band: np.ndarray, n_ref: int) -> np.ndarray:
    """Initial reference: points spread evenly within each band, in proportion to band width,
    with at least two in every band that has two grid points (a narrow band left with none or one
    makes the first levelled error vanish into rounding noise)."""
    labels, first, counts = np.unique(band, return_index=True, return_counts=True)
    widths = np.array([omega[f + c - 1] - omega[f] for f, c in zip(first, counts, strict=True)])
    floor = np.minimum(counts, 2)
    alloc = floor.copy()
    spare = n_ref - alloc.sum()
    if spare < 0:
        return np.round(np.linspace(0, omega.size - 1, n_ref)).astype(np.int64)
    room = counts - alloc
    share = (
        np.sqrt(widths) / np.sqrt(widths).sum()
        if widths.sum() > 0
        else np.ones(labels.size) / labels.size
    )
    while spare > 0:
        want = share * (alloc.sum() + spare) - alloc
        want[room <= 0] = -np.inf
        k = int(np.argmax(want))
        alloc[k] += 1
        room[k] -= 1
        spare -= 1
    idx = [
        f + np.round(np.linspace(0, c - 1, a)).astype(np.int64)
        for f, c, a in zip(first, counts, alloc, strict=True)
        if a > 0
    ]
    return np.unique(np.concatenate(idx))


def _barycentric_eval(x: np.ndarray, xi: np.ndarray, ci: np.ndarray, bi: np.ndarray) -> np.ndarray:
    """Barycentric Lagrange interpolation (second form) of ``(xi, ci)`` at ``x``."""
    diff = x[:, None] - xi[None, :]
    exact = diff == 0
    diff[exact] = 1.0
    t = bi / diff
    out = (t @ ci) / t.sum(axis=1)
    rows, cols = np.nonzero(exact)
    out[rows] = ci[cols]
    return out


def _cosine_coefficients(fn: Callable[[np.ndarray], np.ndarray], degree: int) -> np.ndarray:
    """Coefficients ``a_k`` of a cosine polynomial of known degree from samples (exact solve).

    Samples at the Chebyshev extreme points ``w_j = pi j / M`` (well conditioned: the cosine matrix
    there is the DCT-I matrix).
    """
    if degree == 0:
        return np.atleast_1d(fn(np.array([0.0]))).astype(np.float64)
    w = np.pi * np.arange(degree + 1) / degree
    mat = np.cos(np.outer(w, np.arange(degree + 1)))
    return np.linalg.solve(mat, fn(w))
