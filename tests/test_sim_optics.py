"""Optical terms of the simulator: the noisy-clip moments of ``Saturation``."""

from __future__ import annotations

import torch

from tof_fpn_torch.sim import Saturation


def test_saturation_noisy_moments_match_monte_carlo():
    """Mean and variance of a hard clip of Gaussian samples (none, partly and fully clipped) as
    sampled; a fully clipped sample reads the level with no variance, an unclipped one is left
    alone."""
    level = 100.0
    mean = torch.tensor([0.0, 90.0, 100.0, 110.0, 200.0, 1e5], dtype=torch.float64)
    var = torch.tensor([100.0, 100.0, 400.0, 100.0, 100.0, 1e5], dtype=torch.float64)
    m, v = Saturation(level).noisy_moments(mean, var)
    gen = torch.Generator().manual_seed(0)
    x = mean[:, None] + var.sqrt()[:, None] * torch.randn(
        6, 400_000, generator=gen, dtype=torch.float64
    )
    c = x.clamp(max=level)
    assert torch.allclose(m, c.mean(1), atol=0.05)
    assert torch.allclose(v, c.var(1), rtol=0.02, atol=1e-6)
    assert m[0] == mean[0] and abs(float(v[0]) - 100.0) < 1e-6
    assert float(m[-1]) == level and float(v[-1]) == 0.0


def test_saturation_noisy_moments_have_finite_gradients():
    lv = torch.tensor(100.0, dtype=torch.float64, requires_grad=True)
    mean = torch.tensor([0.0, 100.0, 1e6], dtype=torch.float64, requires_grad=True)
    m, v = Saturation(lv).noisy_moments(mean, torch.full_like(mean, 100.0))
    (m.sum() + v.sum()).backward()
    assert torch.isfinite(lv.grad) and torch.isfinite(mean.grad).all()
    assert float(lv.grad) > 0
