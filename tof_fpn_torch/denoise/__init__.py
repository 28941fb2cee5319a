"""Denoisers for depth maps (run-time layer: torch and kornia only, like :mod:`tof_fpn_torch.runtime`).

May import: torch, kornia, :mod:`tof_fpn_torch.runtime` (validity rule, checks),
:mod:`tof_fpn_torch.constants`. Must not import the design, analysis, simulator or experiments.

Every denoiser is a function plus an ``nn.Module`` whose ``forward(depth, amplitude=None,
sigma=None)`` takes (B, C, H, W) depth, an optional (B, 1, H, W) amplitude and an optional noise
level (:mod:`tof_fpn_torch.denoise._common`), and returns invalid pixels unchanged.

- :class:`NonLocalMeans` / :func:`non_local_means`: non-local means (Buades et al. 2005) with
  per-pixel noise from the amplitude (eq. 2 of Georgiev et al. 2015) and invalid-pixel handling.
- :class:`BM3D` / :func:`bm3d`: block matching and 3-D filtering (Dabov et al. 2007), scalar
  sigma, noise map or noise power spectrum.
- :func:`estimate_sigma`, :func:`estimate_noise_k`: robust noise-level estimators.
"""

from ._sigma import estimate_noise_k, estimate_sigma
from .bm3d import BM3D, bm3d
from .nlm import NonLocalMeans, non_local_means

__all__ = [
    "BM3D",
    "NonLocalMeans",
    "bm3d",
    "estimate_noise_k",
    "estimate_sigma",
    "non_local_means",
]
