"""Non-negative least squares on the normal equations (Lawson-Hanson), shared by the terms
that fit non-negative weights in closed form (the relaying sources and mirror planes of
``multipath_sources``, the light-loss ramps of ``vignetting_field``)."""

from __future__ import annotations

import numpy as np

__all__ = ["NNLS_ITERS", "nnls"]

#: most variables the non-negative least squares frees, one at a time (Lawson-Hanson)
NNLS_ITERS: int = 1000


def nnls(g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``argmin_{x >= 0} x'Gx / 2 - b'x`` for a positive semi-definite ``G`` (n, n): the
    active-set method of Lawson and Hanson ("Solving Least Squares Problems", 1974, ch. 23) on
    the normal equations (with ``G = A'A``, ``b = A'y`` it is ``scipy.optimize.nnls(A, y)``)."""
    n = len(b)
    x = np.zeros(n)
    passive = np.zeros(n, bool)
    tol = 1e-10 * max(float(np.abs(b).max(initial=0.0)), 1e-300)
    ridge = 1e-12 * max(float(np.trace(g)) / max(n, 1), 1e-300)  # a singular G (unlit sources)
    for _ in range(NNLS_ITERS):
        grad = b - g @ x
        free = np.flatnonzero(~passive & (grad > tol))
        if free.size == 0:
            break
        passive[free[np.argmax(grad[free])]] = True
        for _ in range(n + 1):  # the optimum on the passive set, stepped back into x >= 0
            idx = np.flatnonzero(passive)
            z = np.zeros(n)
            z[idx] = np.linalg.solve(g[np.ix_(idx, idx)] + ridge * np.eye(idx.size), b[idx])
            if (z[idx] > 0).all():
                x = z
                break
            neg = idx[z[idx] <= 0]
            ratio = x[neg] / (x[neg] - z[neg])
            x = x + float(ratio.min()) * (z - x)
            x[neg[np.argmin(ratio)]] = 0.0  # the bound that stops the step is hit exactly
            passive &= x > 0
            x[~passive] = 0.0
    return x
