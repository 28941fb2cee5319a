"""Offline design of the FPN notch filters (NumPy / matplotlib; never at run time).

May import: NumPy, SciPy, matplotlib (:mod:`.plot` only), :mod:`tof_fpn_torch.constants`. Must not
import torch or any other layer of the package: it produces taps (NumPy arrays) that
:mod:`tof_fpn_torch.build` hands to the run-time modules.

- :mod:`.remez`: the generalized Remez exchange (frequency-dependent weight and desired response);
  :mod:`.linear_phase`: linear-phase filters from it, optionally with an exact DC gain.
- :mod:`.bands`: notch sets, passbands (eq. 8) and the allowed ``rho``.
- :mod:`.response`: fixed zeros ``A(z)``, zero-phase response, passband ripple.
- :mod:`.notch`: :func:`design_fpn` (Sec. III of Georgiev et al., IEEE SAS 2015): the one way from a
  specification to taps (``design_fpn(...).taps``; :func:`design_fpn_filter` is an alias of that).
- :mod:`.delay`: half-sample delay compensation of odd orders.
- :mod:`.plot`: the magnitude response figure (Fig. 6).
"""

from ..constants import DEFAULT_NOTCHES
from .bands import fpn_bands, max_rho
from .delay import compensate_half_sample, half_sample_taps
from .linear_phase import remez_linear_phase
from .notch import MAX_ORDER, RIPPLE_FLOOR, FPNDesign, design_fpn, design_fpn_filter
from .remez import RemezConvergenceError
from .response import fixed_zero_response, fixed_zero_taps, passband_ripple, zero_phase_response

__all__ = [
    "DEFAULT_NOTCHES",
    "MAX_ORDER",
    "RIPPLE_FLOOR",
    "FPNDesign",
    "RemezConvergenceError",
    "compensate_half_sample",
    "design_fpn",
    "design_fpn_filter",
    "fixed_zero_response",
    "fixed_zero_taps",
    "fpn_bands",
    "half_sample_taps",
    "max_rho",
    "passband_ripple",
    "remez_linear_phase",
    "zero_phase_response",
]
