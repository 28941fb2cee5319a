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
- :class:`SlidingDCT` / :func:`sliding_dct`: sliding-window DCT hard thresholding.
- :class:`HypothesisBilateral`: cost-volume bilateral refinement (Yang et al. 2007), amplitude
  guide.
- :class:`LPAICI`: directional LPA kernels with the ICI rule (Katkovnik, Foi et al.).
- :class:`Bilateral`, :class:`JointBilateral` (amplitude guide), :class:`Guided`: kornia's
  filters with masked invalid pixels and a range parameter that follows the noise.
- :data:`DENOISERS`, :func:`get`, :func:`names`, :func:`register`, :func:`module_class`: the one
  registry (by name, for the CLI, ``tof-fpn clean`` and Table II).
- :func:`estimate_sigma`, :func:`estimate_noise_k`: robust noise-level estimators (defined in
  :mod:`tof_fpn_torch.runtime.noise`, re-exported here).
"""

from ..runtime.noise import estimate_noise_k, estimate_sigma
from .bilateral import Bilateral, JointBilateral, bilateral, joint_bilateral
from .bm3d import BM3D, bm3d
from .guided import Guided, guided
from .hypbi import HypothesisBilateral, hypothesis_bilateral
from .lpa_ici import LPAICI, lpa_ici
from .nlm import NonLocalMeans, non_local_means
from .registry import DENOISERS, canonical, describe, get, module_class, names, register, scriptable
from .sliding_dct import SlidingDCT, sliding_dct

__all__ = [
    "BM3D",
    "DENOISERS",
    "Bilateral",
    "Guided",
    "HypothesisBilateral",
    "JointBilateral",
    "LPAICI",
    "NonLocalMeans",
    "SlidingDCT",
    "bilateral",
    "bm3d",
    "canonical",
    "describe",
    "estimate_noise_k",
    "estimate_sigma",
    "get",
    "guided",
    "hypothesis_bilateral",
    "joint_bilateral",
    "lpa_ici",
    "module_class",
    "names",
    "non_local_means",
    "register",
    "scriptable",
    "sliding_dct",
]
