"""Analysis of depth data: quality metrics and stripe (FPN) estimation (torch, offline use).

May import: torch, kornia, :mod:`tof_fpn_torch.runtime` (the validity rule and the argument
checks), :mod:`tof_fpn_torch.constants`. Must not import the design, the simulator, the
experiments or the CLI. Its results feed the builders (:mod:`tof_fpn_torch.build`), the
experiments and the diagnosis; nothing in the run-time package depends on it.

- :mod:`.metrics`: PSNR (eq. 9), RMSE, MAE, the LOW / IMP shares of Table II.
- :mod:`.stripes`: :func:`estimate_stripes`, periodic column / row patterns in depth frames.
- :mod:`.calibrate`: :func:`calibrate_fixed_pattern` -> :class:`FixedPattern` (many frames).
- :mod:`.calibrate_complex`: :func:`calibrate_complex_pattern` -> :class:`ComplexPattern` (complex
  read-out offsets from many frames).
- :mod:`.folder_pattern`: :func:`learn_folder_pattern` -> :class:`LearnedPattern` (the fixed
  pattern one camera's frames of different scenes share, confirmed by two halves of them).
- :mod:`.stripe_energy`: :func:`column_stripe_energy` (white noise does not count),
  :func:`lowpass_change`.
"""

from . import metrics
from .calibrate import FixedPattern, calibrate_fixed_pattern
from .calibrate_complex import ComplexPattern, calibrate_complex_pattern
from .folder_pattern import LearnedPattern, learn_folder_pattern
from .metrics import impulsive_fraction, low_sensing_fraction, mae, mse, psnr, rmse
from .stripe_energy import StripeEnergy, column_stripe_energy, lowpass_change
from .stripes import StripeComponent, StripeEstimate, estimate_stripes

__all__ = [
    "ComplexPattern",
    "FixedPattern",
    "LearnedPattern",
    "StripeComponent",
    "StripeEnergy",
    "StripeEstimate",
    "calibrate_complex_pattern",
    "calibrate_fixed_pattern",
    "column_stripe_energy",
    "estimate_stripes",
    "learn_folder_pattern",
    "lowpass_change",
    "impulsive_fraction",
    "low_sensing_fraction",
    "mae",
    "metrics",
    "mse",
    "psnr",
    "rmse",
]
