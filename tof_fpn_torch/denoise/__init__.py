"""Denoisers for depth maps (run-time layer: torch and kornia only, like :mod:`tof_fpn_torch.runtime`).

May import: torch, kornia, :mod:`tof_fpn_torch.runtime` (validity rule, checks),
:mod:`tof_fpn_torch.constants`. Must not import the design, analysis, simulator or experiments.

- :class:`NonLocalMeans` / :func:`non_local_means`: non-local means (Buades et al. 2005) with
  per-pixel noise from the amplitude (eq. 2 of Georgiev et al. 2015) and invalid-pixel handling.
- :func:`estimate_sigma`, :func:`estimate_noise_k`: robust noise-level estimators.
"""

from ._sigma import estimate_noise_k, estimate_sigma
from .nlm import NonLocalMeans, non_local_means

__all__ = ["NonLocalMeans", "estimate_noise_k", "estimate_sigma", "non_local_means"]
