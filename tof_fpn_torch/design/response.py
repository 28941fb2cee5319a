"""Responses of linear-phase FIR filters: the fixed zeros ``A(z)``, zero-phase response, ripple."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..constants import DEFAULT_NOTCHES
from .bands import check_notches

__all__ = ["fixed_zero_response", "fixed_zero_taps", "passband_ripple", "zero_phase_response"]


def fixed_zero_taps(notches: Sequence[float] = DEFAULT_NOTCHES) -> np.ndarray:
    """Coefficients of ``A(z)``: ``1 - 2cos(w0) z^-1 + z^-2`` per notch in (0, pi), ``1 + z^-1`` at pi."""
    a = np.ones(1)
    for w0 in check_notches(notches):
        factor = [1.0, 1.0] if w0 >= np.pi else [1.0, -2.0 * math.cos(w0), 1.0]
        a = np.convolve(a, factor)
    return a


def fixed_zero_response(
    omega: np.ndarray, notches: Sequence[float] = DEFAULT_NOTCHES
) -> np.ndarray:
    """Signed zero-phase response ``A(w)`` of :func:`fixed_zero_taps` (e.g. ``A1(w) = 1 + 2cos w``)."""
    omega = np.asarray(omega, dtype=np.float64)
    out = np.ones_like(omega)
    for w0 in check_notches(notches):
        out = out * (2 * np.cos(omega / 2) if w0 >= np.pi else 2 * np.cos(omega) - 2 * math.cos(w0))
    return out


def zero_phase_response(taps: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Real response ``H(w)`` of symmetric taps, ``H(e^jw) = e^{-j w N/2} H(w)``."""
    taps = np.asarray(taps, dtype=np.float64)
    n = np.arange(taps.size) - (taps.size - 1) / 2
    return np.cos(np.outer(np.asarray(omega, dtype=np.float64), n)) @ taps


def passband_ripple(taps: np.ndarray, bands: np.ndarray, num_points: int = 4096) -> np.ndarray:
    """``max |H(w) - 1|`` in each band; shape ``(K,)``.

    Evaluated on a uniform FFT grid of ``num_points + 1`` frequencies over ``[0, pi]`` plus the band
    edges; every local maximum inside a band is then re-evaluated exactly at the vertex of the
    parabola through its three grid values (the peak to ~1e-12 relative).
    """
    taps = np.asarray(taps, dtype=np.float64)
    bands = np.asarray(bands, dtype=np.float64).reshape(-1, 2)
    omega = np.linspace(0.0, np.pi, num_points + 1)
    step = omega[1]
    spectrum = np.fft.rfft(taps, 2 * num_points)
    err = np.abs((spectrum * np.exp(1j * omega * (taps.size - 1) / 2)).real - 1.0)
    edge_err = np.abs(zero_phase_response(taps, bands.ravel()) - 1.0).reshape(-1, 2).max(axis=1)
    out = np.empty(bands.shape[0])
    for k, (lo, hi) in enumerate(bands):
        idx = np.flatnonzero((omega >= lo) & (omega <= hi))
        e = err[idx]
        out[k] = max(edge_err[k], e.max(initial=0.0))
        if e.size < 3:
            continue
        i = np.flatnonzero((e[1:-1] >= e[:-2]) & (e[1:-1] >= e[2:])) + 1
        a, b, c = e[i - 1], e[i], e[i + 1]
        denom = a - 2 * b + c
        shift = np.where(denom < 0, 0.5 * (a - c) / np.where(denom < 0, denom, -1.0), 0.0)
        vertex = np.clip(omega[idx[i]] + np.clip(shift, -1, 1) * step, lo, hi)
        refined = np.abs(zero_phase_response(taps, vertex) - 1.0)
        out[k] = max(out[k], refined.max(initial=0.0))
    return out
