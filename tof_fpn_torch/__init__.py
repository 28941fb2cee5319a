"""tof_fpn_torch: fixed-pattern-noise suppression for Time-of-Flight depth data.

Offline design (NumPy/SciPy): :mod:`tof_fpn_torch.design`, :mod:`tof_fpn_torch.remez`.
"""

from .design import FPNDesign, design_fpn, design_fpn_filter
from .remez import RemezConvergenceError

__version__ = "0.1.0"

__all__ = [
    "FPNDesign",
    "RemezConvergenceError",
    "__version__",
    "design_fpn",
    "design_fpn_filter",
]
