"""The paper's depth-domain model: eq. (2) noise and the reconstructed eq. (10) FPN."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.sim import (
    FPN_ALPHA,
    FPN_BETA,
    FPN_GAMMA,
    DepthFPN,
    add_depth_fpn,
    add_depth_noise,
    depth_noise_std,
    fpn_intensity,
    fpn_pattern,
    noise_lambda_for_psnr,
    synthetic_scene,
)

FREQS = [math.pi, 2 * math.pi / 3]


def test_fpn_is_a_quarter_at_very_low_amplitude_and_under_5_percent_above_300():
    a = torch.linspace(0, 1000, 2001, dtype=torch.float64)
    k = fpn_intensity(a)
    assert 0.24 <= float(k[0]) <= 0.26
    assert float(k[a >= 300].max()) < 0.05
    assert bool((k[1:] < k[:-1]).all())  # falls monotonically with amplitude
    # k(A) = sqrt(beta gamma) exp(alpha A / (2 A_ref)), A_ref = 300: each parameter acts so
    ref = math.sqrt(FPN_BETA * FPN_GAMMA) * torch.exp(FPN_ALPHA * a / 600.0)
    torch.testing.assert_close(k, ref, rtol=1e-12, atol=0)
    torch.testing.assert_close(fpn_intensity(a, alpha=2 * FPN_ALPHA), k * k / k[0])
    torch.testing.assert_close(fpn_intensity(a, beta=4 * FPN_BETA), 2 * k)
    torch.testing.assert_close(fpn_intensity(a, gamma=FPN_GAMMA / 4), k / 2)
    torch.testing.assert_close(fpn_intensity(2 * a, amplitude_ref=600.0), k)


def test_fpn_in_depth_has_those_shares():
    """Measured on depth maps: peak |D_FPN - D| / D ~ 25 % at A ~ 0, < 5 % for A >= 300."""
    h, w = 8, 60
    depth = torch.full((2, 1, h, w), 4.0, dtype=torch.float64)
    amp = torch.stack([torch.full((1, h, w), 0.0), torch.full((1, h, w), 300.0)]).double()
    out = add_depth_fpn(depth, amp, FREQS, [0.0, 0.0])
    rel = ((out - depth).abs() / depth).flatten(1).max(dim=1).values
    assert 0.24 <= float(rel[0]) <= 0.26
    assert float(rel[1]) < 0.05
    profile = (out - depth)[0, 0, 0].numpy()
    spec = np.abs(np.fft.rfft(profile)) ** 2
    assert spec[[w // 3, w // 2]].sum() / spec.sum() > 0.999  # only 2 pi / 3 and pi
    assert torch.allclose(out[0, 0], out[0, 0, :1].expand(h, w))  # column stripes


def test_fpn_matches_independent_numpy_formula_and_axis():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.5, 7.5, size=(2, 1, 5, 7))
    a = rng.uniform(0, 400, size=(2, 1, 5, 7))
    th = [0.3, -1.0]
    for axis, dim in (("columns", 3), ("rows", 2)):
        got = DepthFPN(tuple(FREQS), tuple(th), axis=axis)(torch.from_numpy(d), torch.from_numpy(a))
        x = np.arange(d.shape[dim])
        p = (np.cos(FREQS[0] * x + th[0]) + np.cos(FREQS[1] * x + th[1])) / 2
        p = p.reshape((1, 1, 1, -1) if dim == 3 else (1, 1, -1, 1))
        k = np.sqrt(FPN_BETA * FPN_GAMMA * np.exp(FPN_ALPHA * a / 300.0))
        np.testing.assert_allclose(got.numpy(), d * (1 + k * p), rtol=1e-12)


def test_fpn_keeps_invalid_pixels_and_inputs():
    depth = torch.full((1, 1, 4, 6), 3.0)
    depth[0, 0, 1, 2] = float("nan")
    depth[0, 0, 2, 3] = 0.0
    amp = torch.full_like(depth, 50.0)
    d0, a0 = depth.clone(), amp.clone()
    out = DepthFPN()(depth, amp)
    assert torch.isnan(out[0, 0, 1, 2]) and out[0, 0, 2, 3] == 0
    assert torch.equal(depth.nan_to_num(-1), d0.nan_to_num(-1)) and torch.equal(amp, a0)


def test_fpn_torchscript_matches_eager():
    g = torch.Generator().manual_seed(1)
    depth = 0.5 + 7 * torch.rand((2, 1, 9, 11), generator=g)
    amp = 300 * torch.rand((2, 1, 9, 11), generator=g)
    mod = DepthFPN(axis="rows")
    torch.testing.assert_close(torch.jit.script(mod)(depth, amp), mod(depth, amp))
    fn = torch.jit.script(add_depth_fpn)
    torch.testing.assert_close(
        fn(depth, amp, FREQS, [0.0, 0.0]), add_depth_fpn(depth, amp, FREQS, [0.0, 0.0])
    )


def test_depth_noise_follows_eq2():
    g = torch.Generator().manual_seed(4)
    amps = torch.tensor([10.0, 20.0, 40.0, 80.0, 160.0, 320.0], dtype=torch.float64)
    amp = amps.view(1, 1, -1, 1).expand(1, 1, 6, 4000).contiguous()
    depth = torch.full_like(amp, 3.0)
    lam = 400.0
    noisy = add_depth_noise(depth, amp, lam, generator=g)
    sigma = (noisy - depth)[0, 0].std(dim=1)
    slope = np.polyfit(np.log(amps.numpy()), np.log(sigma.numpy()), 1)[0]
    assert -1.05 < slope < -0.95
    expected = depth_noise_std(amps, lam)
    torch.testing.assert_close(sigma, expected, rtol=0.05, atol=0)


def test_depth_model_errors():
    d = torch.full((1, 1, 4, 4), 2.0)
    a = torch.full((1, 1, 4, 4), 10.0)
    with pytest.raises(ValueError, match="amplitude"):
        add_depth_fpn(d, -a, FREQS, [0.0, 0.0])
    with pytest.raises(ValueError, match="depth must be >= 0"):
        add_depth_fpn(-d, a, FREQS, [0.0, 0.0])
    with pytest.raises(ValueError, match="shape"):
        add_depth_noise(d, a[..., :2], 1.0)
    with pytest.raises(ValueError, match="lam"):
        add_depth_noise(d, a, -1.0)
    with pytest.raises(ValueError, match="frequencies"):
        DepthFPN(frequencies=(4.0,))
    with pytest.raises(ValueError, match="axis"):
        DepthFPN(axis="diagonal")
    with pytest.raises(ValueError, match="beta"):
        fpn_intensity(a, beta=0.0)
    with pytest.raises(ValueError, match="equal length"):
        fpn_pattern(8, FREQS, [0.0])


def test_noise_lambda_for_psnr_reaches_the_target():
    """Table I's protocol: FPN (about 24.5 dB) then noise down to 21.26 dB."""
    scene = synthetic_scene(seed=0)
    d_fpn = DepthFPN()(scene.depth, scene.amplitude)
    lam = noise_lambda_for_psnr(scene.depth, d_fpn, scene.amplitude, 21.26, amplitude_floor=10.0)
    g = torch.Generator().manual_seed(0)
    noisy = add_depth_noise(d_fpn, scene.amplitude, lam, amplitude_floor=10.0, generator=g)
    assert abs(float(psnr(noisy, scene.depth)) - 21.26) < 0.15
    with pytest.raises(ValueError, match="above the PSNR"):
        noise_lambda_for_psnr(scene.depth, d_fpn, scene.amplitude, 40.0)
