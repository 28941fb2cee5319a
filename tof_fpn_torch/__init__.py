"""tof_fpn_torch: fixed-pattern-noise suppression for Time-of-Flight depth data.

Offline design (NumPy/SciPy): :mod:`tof_fpn_torch.design`, :mod:`tof_fpn_torch.remez`.
"""

from . import denoise, metrics, sim
from .denoise import NonLocalMeans, non_local_means
from .design import FPNDesign, design_fpn, design_fpn_filter
from .fpn_filter import FPNFilter
from .fusion import AmplitudeFusion
from .metrics import psnr
from .remez import RemezConvergenceError
from .sim import Camera, Scene, Simulation, planar_scene, synthetic_scene
from .stripes import StripeComponent, StripeEstimate, estimate_stripes
from .suppression import FPNSuppression

__version__ = "0.1.0"

__all__ = [
    "AmplitudeFusion",
    "Camera",
    "FPNDesign",
    "FPNFilter",
    "FPNSuppression",
    "NonLocalMeans",
    "RemezConvergenceError",
    "Scene",
    "Simulation",
    "StripeComponent",
    "StripeEstimate",
    "__version__",
    "denoise",
    "design_fpn",
    "design_fpn_filter",
    "estimate_stripes",
    "metrics",
    "non_local_means",
    "planar_scene",
    "psnr",
    "sim",
    "synthetic_scene",
]
