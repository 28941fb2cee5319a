"""The diagnosing model's Rician amplitude law against SciPy, and its hand-written derivative."""

import numpy as np
import torch
from scipy import stats

from tof_fpn_torch.diagnosis.noise import _Laguerre, rician


def test_rician_mean_and_sd_match_scipy_rice():
    """Mean and sd of ``|a0 + s (xi_1 + j xi_2)|`` equal ``scipy.stats.rice`` (b = a0 / s,
    scale s), from noise-dominated (a0 = 0) to a strong return (a0 / s = 25; SciPy's moments
    are NaN further out, where the mean is ``a0 + s^2 / 2 a0`` to O(s^4 / a0^3))."""
    a0 = torch.tensor([0.0, 0.3, 1.0, 2.5, 7.0, 15.0, 25.0], dtype=torch.float64)
    s = torch.full_like(a0, 1.0) * torch.tensor(1.7, dtype=torch.float64)
    a0 = a0 * 1.7
    mean, sd = rician(a0, s)
    ref = stats.rice(b=(a0 / s).numpy(), scale=s.numpy())
    np.testing.assert_allclose(mean.numpy(), ref.mean(), rtol=1e-10)
    np.testing.assert_allclose(sd.numpy(), ref.std(), rtol=1e-6)
    far, one = torch.tensor([400.0], dtype=torch.float64), torch.tensor([1.0], dtype=torch.float64)
    mean, sd = rician(far, one)
    np.testing.assert_allclose(mean.item(), 400.0 + 1.0 / 800.0, rtol=1e-9)
    np.testing.assert_allclose(sd.item(), 1.0, rtol=1e-3)


def test_laguerre_gradient_equals_autograd_through_the_bessel_functions():
    """``f'(x) = i0e(x) + i1e(x)`` (the derivation in ``_Laguerre``) against autograd through
    ``torch.special`` and against ``gradcheck`` (finite differences)."""
    x = torch.tensor([1e-4, 0.05, 0.7, 3.0, 11.0, 60.0, 900.0], dtype=torch.float64)
    x.requires_grad_(True)
    (g,) = torch.autograd.grad(_Laguerre.apply(x).sum(), x)
    y = (1 + 2 * x) * torch.special.i0e(x) + 2 * x * torch.special.i1e(x)
    (g_ref,) = torch.autograd.grad(y.sum(), x)
    torch.testing.assert_close(g, g_ref, rtol=1e-12, atol=1e-15)
    assert torch.autograd.gradcheck(_Laguerre.apply, (x[:5].detach().requires_grad_(True),))
