"""Per-reading log-densities of the diagnosis likelihood and the robust per-pixel centre their
deviations are taken about (shared by :mod:`~tof_fpn_torch.diagnosis.likelihood` and the
terms that evaluate frames themselves, e.g. ``noise_floor_tails``).
"""

from __future__ import annotations

import math

import torch

__all__ = ["CENTRE_Z", "LOG_2PI", "gauss_log_density", "pixel_centre", "student_log_density"]

#: Readings farther than this many predicted sd from their pixel's temporal median are left out
#: of the centre about which a heavy-tailed law's deviations are taken (outliers, not tails).
CENTRE_Z: float = 6.0

#: log(2 pi), of every Gaussian log-density
LOG_2PI: float = math.log(2 * math.pi)


def gauss_log_density(r: torch.Tensor, var) -> torch.Tensor:
    """Log-density of Gaussian residuals ``r`` of variance ``var``."""
    return -0.5 * r * r / var - 0.5 * torch.log(var) - 0.5 * LOG_2PI


def student_log_density(r: torch.Tensor, var: torch.Tensor, tail) -> torch.Tensor:
    """Log-density of Student-t residuals ``r`` with ``dof = 1 / tail`` (> 2) degrees of
    freedom and variance ``var`` (scale ``s^2 = var (dof - 2) / dof``)."""
    nu = 1.0 / torch.as_tensor(tail, dtype=torch.float64)
    s2 = var * (nu - 2.0) / nu
    return (
        torch.lgamma((nu + 1.0) / 2.0)
        - torch.lgamma(nu / 2.0)
        - 0.5 * torch.log(nu * math.pi * s2)
        - 0.5 * (nu + 1.0) * torch.log1p(r * r / (nu * s2))
    )


def pixel_centre(x: torch.Tensor, valid: torch.Tensor, sd: torch.Tensor) -> torch.Tensor:
    """Each pixel's temporal mean (1, P) of its valid readings ``x`` (T, P) within
    :data:`CENTRE_Z` sd ``sd`` of their median, as data (no gradient): the plain mean where no
    reading is that far, a centre an outlier does not move where one is."""
    x, sd = x.detach(), sd.detach()
    med = torch.where(valid, x, torch.full_like(x, float("nan"))).nanmedian(dim=0).values
    dev = x - med.nan_to_num(0.0).view(1, -1)
    keep = valid & (dev.abs() <= CENTRE_Z * sd)
    k = keep.sum(0).clamp_min(1)
    out = torch.where(keep, x, torch.zeros_like(x)).sum(0) / k
    return torch.where(keep.any(0), out, med.nan_to_num(0.0)).view(1, -1)
