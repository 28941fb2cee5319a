"""Figure of a designed filter (matplotlib, offline only): Fig. 6 of the paper."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..plotting import pyplot
from .notch import FPNDesign
from .response import zero_phase_response

__all__ = ["plot_response"]


def plot_response(design: FPNDesign, path: str | Path, *, num_points: int = 4096) -> Path:
    """Fig. 6 of Georgiev et al. (2015): magnitude response in dB with a zoomed passband inset.

    The inset shows ``H(w) - 1`` (zero-phase, linear) in the passbands, i.e. the ripple ``delta``.
    """
    plt = pyplot()
    omega = np.linspace(0.0, math.pi, num_points)
    h = zero_phase_response(design.taps, omega)
    mag_db = 20 * np.log10(np.maximum(np.abs(h), 1e-12))
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ax.plot(omega / math.pi, mag_db, lw=1.2)
    for lo, hi in design.bands:
        ax.axvspan(lo / math.pi, hi / math.pi, color="tab:green", alpha=0.08, lw=0)
    for w0 in design.notches:
        ax.axvline(w0 / math.pi, color="tab:red", ls=":", lw=1)
    ax.set_ylim(-50, 5)
    ax.set_xlim(0, 1)
    ax.set_xlabel(r"Normalized frequency ($\omega/\pi$)")
    ax.set_ylabel("Magnitude (dB)")
    ax.set_title(
        f"FPN notch filter N = {design.order}, rho = {design.rho:g}: "
        f"ripple {design.ripple_db:.1f} dB (delta = {design.ripple:.2e})"
    )
    ax.grid(alpha=0.3)
    inset = ax.inset_axes([0.08, 0.12, 0.42, 0.35])
    for lo, hi in design.bands:
        sel = (omega >= lo) & (omega <= hi)
        inset.plot(omega[sel] / math.pi, h[sel] - 1.0, color="tab:blue", lw=1)
    lim = 1.3 * design.ripple
    inset.set_ylim(-lim, lim)
    inset.set_xlim(0, 1)
    inset.axhline(design.ripple, color="gray", ls="--", lw=0.7)
    inset.axhline(-design.ripple, color="gray", ls="--", lw=0.7)
    inset.set_title("passband: H(w) - 1", fontsize=8)
    inset.tick_params(labelsize=7)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
