"""Analysis of depth data: quality metrics and stripe (FPN) estimation (torch, offline use).

May import: torch, kornia, :mod:`tof_fpn_torch.runtime` (the validity rule and the argument
checks), :mod:`tof_fpn_torch.constants`. Must not import the design, the simulator, the
experiments or the CLI. Its results feed the builders (:mod:`tof_fpn_torch.build`), the
experiments and the diagnosis; nothing in the run-time package depends on it.

- :mod:`.metrics`: PSNR (eq. 9), RMSE, MAE, the LOW / IMP shares of Table II.
- :mod:`.stripes`: :func:`estimate_stripes`, periodic column / row patterns in depth frames.
"""

from . import metrics
from .metrics import impulsive_fraction, low_sensing_fraction, mae, mse, psnr, rmse
from .stripes import StripeComponent, StripeEstimate, estimate_stripes

__all__ = [
    "StripeComponent",
    "StripeEstimate",
    "estimate_stripes",
    "impulsive_fraction",
    "low_sensing_fraction",
    "mae",
    "metrics",
    "mse",
    "psnr",
    "rmse",
]
