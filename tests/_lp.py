"""An independent optimum for the notch design: the minimax ripple by linear programming (HiGHS).

The unknowns are the symmetric taps of ``H`` themselves (no factorisation ``A(z) G(z)``, no Remez):
``min t`` subject to ``|H(w_i) - 1| <= t`` on a dense grid of the passbands, the zeros as
equalities ``H(w0) = 0`` and, optionally, ``H(0) = 1``. A grid LP is a relaxation of the
continuous problem, so its optimum is a lower bound of the true minimax ripple.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linprog


def lp_minimax_ripple(
    order: int, bands: np.ndarray, notches, num_points: int = 1500, unit_dc: bool = False
) -> float:
    half = order // 2 + 1
    n = np.arange(half)
    omega = np.concatenate(
        [np.linspace(lo, hi, max(2, int(num_points * (hi - lo) / math.pi))) for lo, hi in bands]
    )

    def basis(w):
        # H(w) = sum_n h[n] cos(w (n - N/2)); pair h[n] with h[N - n].
        b = 2 * np.cos(np.outer(w, n - order / 2))
        if order % 2 == 0:
            b[:, -1] /= 2  # the centre tap appears once
        return b

    b = basis(omega)
    ones = np.ones((omega.size, 1))
    a_ub = np.block([[b, -ones], [-b, -ones]])
    b_ub = np.concatenate([np.ones(omega.size), -np.ones(omega.size)])
    eq_w = list(notches) + ([0.0] if unit_dc else [])
    a_eq = np.hstack([basis(np.asarray(eq_w, dtype=float)), np.zeros((len(eq_w), 1))])
    b_eq = np.array([0.0] * len(notches) + ([1.0] if unit_dc else []))
    c = np.zeros(half + 1)
    c[-1] = 1.0
    res = linprog(
        c,
        A_ub=a_ub,
        b_ub=b_ub,
        A_eq=a_eq,
        b_eq=b_eq,
        bounds=[(None, None)] * (half + 1),
        method="highs",
        options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10},
    )
    assert res.status == 0, res.message
    return float(res.x[-1])
