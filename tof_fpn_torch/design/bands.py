"""Notch sets and passbands of the FPN notch design (eq. 8), with the argument checks.

The one place that says which notch frequencies and which ``rho`` are allowed: the design, the
builders and the experiments all call :func:`check_notches`, :func:`check_rho`, :func:`max_rho` and
:func:`fpn_bands`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..constants import DEFAULT_NOTCHES

__all__ = ["check_notches", "check_rho", "fpn_bands", "max_rho"]

_EDGE_TOL = 1e-12


def check_notches(notches: Sequence[float]) -> np.ndarray:
    """Notch frequencies as a sorted float64 array; ``ValueError`` unless distinct, in (0, pi]."""
    try:
        w = np.asarray(notches, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"notches must be a sequence of floats, got {notches!r}") from exc
    if w.size == 0:
        raise ValueError("notches must hold at least one frequency in (0, pi], got none")
    if not np.all(np.isfinite(w)):
        raise ValueError(f"notches must be finite, got {w.tolist()}")
    bad = w[(w <= 0) | (w > np.pi + _EDGE_TOL)]
    if bad.size:
        raise ValueError(
            f"notches must lie in (0, pi] (radians per sample), got {bad.tolist()} in {w.tolist()}"
        )
    w = np.sort(np.minimum(w, np.pi))
    if np.any(np.diff(w) <= 0):
        raise ValueError(f"notches must be distinct, got {w.tolist()}")
    return w


def check_rho(rho: float) -> float:
    """``rho`` as a float; ``ValueError`` unless a finite real number > 0."""
    if isinstance(rho, bool) or not isinstance(rho, (int, float, np.floating, np.integer)):
        raise ValueError(f"rho must be a real number, got {rho!r}")
    rho = float(rho)
    if not math.isfinite(rho) or rho <= 0:
        raise ValueError(f"rho must be finite and > 0, got {rho!r}")
    return rho


def max_rho(notches: Sequence[float] = DEFAULT_NOTCHES) -> float:
    """Largest ``rho`` for which :func:`fpn_bands` accepts ``notches``: the transition half-width
    ``rho pi`` may take the whole gap to 0 and to pi, and half the gap between two notches.
    1/6 for the default notches (2pi/3, pi)."""
    w = check_notches(notches)
    gaps = [w[0], *(np.diff(w) / 2)]
    if w[-1] < np.pi:
        gaps.append(np.pi - w[-1])
    return float(min(gaps) / np.pi)


def fpn_bands(rho: float, notches: Sequence[float] = DEFAULT_NOTCHES) -> np.ndarray:
    """Passbands ``X`` with transition half-width ``rho * pi`` around every notch (eq. 8).

    For the default notches ``X = [0, 2pi/3 - rho pi] U [2pi/3 + rho pi, pi - rho pi]``, which needs
    ``0 < rho <= 1/6`` (:func:`max_rho`). For custom notches a band follows the last notch up to
    ``pi`` when that notch is below ``pi``.

    Returns:
        ``(K, 2)`` float64 band edges in radians.

    Raises:
        ValueError: ``rho`` not finite/positive, or bands that would be empty or overlap.
    """
    rho = check_rho(rho)
    w = check_notches(notches)
    limit = max_rho(w)
    if rho > limit * (1 + 1e-12):
        default = w.size == len(DEFAULT_NOTCHES) and np.allclose(w, DEFAULT_NOTCHES)
        where = "the default notches (2pi/3, pi)" if default else "notches"
        raise ValueError(
            f"rho={rho!r} makes the passbands empty or overlap; rho must lie in "
            f"(0, {limit:.6g}] for {where} {w.tolist()}"
        )
    half = rho * np.pi
    edges = [(0.0, w[0] - half)]
    for a, b in zip(w[:-1], w[1:], strict=True):
        edges.append((a + half, b - half))
    if w[-1] < np.pi:
        edges.append((w[-1] + half, np.pi))
    bands = np.array(edges)
    thin = bands[:, 1] - bands[:, 0] <= _EDGE_TOL
    bands[thin, 1] = bands[thin, 0]  # a band of width ~0 (rho = max_rho) is one point
    return bands
