"""Tests of the kornia-based denoisers (Bilateral, JointBilateral, Guided) and the registry.

They wrap kornia: on valid data they are kornia's own functions (bit for bit); with holes and a
per-pixel noise level they do what kornia cannot, measured here on a simulated ToF frame.
"""

from __future__ import annotations

import math

import pytest
import torch
from kornia.filters import bilateral_blur, guided_blur, joint_bilateral_blur

from tof_fpn_torch import constants as K
from tof_fpn_torch import denoise
from tof_fpn_torch.denoise import (
    Bilateral,
    Guided,
    JointBilateral,
    bilateral,
    guided,
    joint_bilateral,
)
from tof_fpn_torch.sim import synthetic_scene


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _frame(seed: int = 0, size=(64, 80)):
    """A ToF-like frame: synthetic scene, depth noise 4 / A, a noisy amplitude."""
    scene = synthetic_scene(*size, seed=seed)
    g = torch.Generator().manual_seed(10 + seed)
    amp = scene.amplitude.clamp_min(20.0) + 2.0 * torch.randn(scene.depth.shape, generator=g)
    noisy = scene.depth + (4.0 / amp) * torch.randn(scene.depth.shape, generator=g)
    return scene.depth, amp, noisy


def _psnr(out, gt, mask):
    return float(10 * torch.log10(K.D_MAX**2 / (out - gt)[mask].square().mean()))


def test_equal_to_kornia_on_valid_data():
    _, amp, x = _frame()
    x2 = torch.cat([x, x.flip(-1)])
    a2 = torch.cat([amp, amp.flip(-1)])
    torch.testing.assert_close(
        bilateral(x2, sigma_color=0.05), bilateral_blur(x2, 9, 0.05, (3.0, 3.0)), atol=0, rtol=0
    )
    torch.testing.assert_close(
        joint_bilateral(x2, a2, sigma_color=4.0, kernel_size=5, sigma_space=2.0),
        joint_bilateral_blur(x2, a2, 5, 4.0, (2.0, 2.0)),
        atol=0,
        rtol=0,
    )
    torch.testing.assert_close(guided(x2, eps=1e-3), guided_blur(x2, x2, 9, 1e-3), atol=0, rtol=0)
    torch.testing.assert_close(
        guided(x2, a2, guide="amplitude", eps=4.0, kernel_size=5),
        guided_blur(a2, x2, 5, 4.0),
        atol=0,
        rtol=0,
    )
    # a scalar noise level: sigma_color = color * sigma (kornia given a per-image tensor)
    torch.testing.assert_close(
        bilateral(x2, sigma=0.02, color=2.5),
        bilateral_blur(x2, 9, 0.05, (3.0, 3.0)),
        atol=1e-5,
        rtol=0,
    )


def test_per_pixel_range_sigma_is_kornia_at_each_level():
    """Two noise levels (left / right half): each half is kornia's result at its own sigma."""
    _, _, x = _frame()
    sig = torch.full_like(x, 0.01)
    sig[..., 40:] = 0.04
    out = bilateral(x, sigma=sig, color=2.0)
    left = bilateral_blur(x, 9, 0.02, (3.0, 3.0))
    right = bilateral_blur(x, 9, 0.08, (3.0, 3.0))
    torch.testing.assert_close(out[..., :40], left[..., :40], atol=1e-5, rtol=0)
    torch.testing.assert_close(out[..., 40:], right[..., 40:], atol=1e-5, rtol=0)
    g = guided(x, sigma=sig, color=2.0)
    torch.testing.assert_close(
        g[..., :40], guided_blur(x, x, 9, 0.02**2)[..., :40], atol=1e-5, rtol=0
    )
    torch.testing.assert_close(
        g[..., 40:], guided_blur(x, x, 9, 0.08**2)[..., 40:], atol=1e-5, rtol=0
    )


@pytest.mark.parametrize("code", [0.0, math.nan])
def test_beats_kornia_on_tof_data_with_holes(code):
    gt, amp, noisy = _frame(seed=1, size=(96, 112))
    g = torch.Generator().manual_seed(3)
    holes = torch.rand(gt.shape, generator=g) < 0.05
    holes[..., 30:38, 40:52] = True
    x = torch.where(holes, torch.full_like(noisy, code), noisy)
    a = amp  # a camera reports the amplitude of a pixel whose depth it marks invalid
    ok = ~holes
    s = float((4.0 / amp).median())
    p_in = _psnr(noisy, gt, ok)
    cases = {
        "bilateral": (bilateral(x, a), bilateral_blur(x, 9, 2 * s, (3.0, 3.0))),
        "guided": (guided(x, a), guided_blur(x, x, 9, (2 * s) ** 2)),
        "joint": (
            joint_bilateral(x, a, sigma_color=6.0),
            joint_bilateral_blur(x, a, 9, 6.0, (3.0, 3.0)),
        ),
    }
    for name, (ours, kor) in cases.items():
        assert torch.equal(ours[holes].isnan(), x[holes].isnan()), name
        assert bool((ours[holes].nan_to_num(7.0) == x[holes].nan_to_num(7.0)).all()), name
        assert bool(torch.isfinite(ours[ok]).all()), name
        p_ours = _psnr(ours, gt, ok)
        p_k = _psnr(kor.nan_to_num(0.0), gt, ok)  # kornia spreads NaN: count them as 0
        assert p_ours > p_k + 1.0, (name, code, p_in, p_ours, p_k)
        if (
            name != "joint"
        ):  # amplitude-guided smoothing crosses depth edges without amplitude edges
            assert p_ours > p_in + 2.0, (name, code, p_in, p_ours)


def test_noise_law_from_amplitude_helps():
    gt, amp, noisy = _frame(seed=2, size=(96, 112))
    ok = torch.ones_like(gt, dtype=torch.bool)
    assert _psnr(bilateral(noisy, amp), gt, ok) > _psnr(bilateral(noisy), gt, ok) + 0.5
    assert _psnr(guided(noisy, amp), gt, ok) > _psnr(guided(noisy), gt, ok) - 0.1  # ~ equal


def test_degenerate_inputs():
    x = 1.0 + 0.01 * torch.randn(2, 1, 12, 12, generator=torch.Generator().manual_seed(0))
    x[1] = math.nan  # all invalid
    for m in (Bilateral(), Guided()):
        out = m(x, sigma=0.01)
        assert bool(out[1].isnan().all()) and bool(torch.isfinite(out[0]).all())
        torch.testing.assert_close(m(x[:1], sigma=0.0), x[:1], atol=0, rtol=0)
        assert m(x[:1].double(), sigma=0.01).dtype == torch.float64
    for m in (Bilateral(), Guided(), JointBilateral()):
        with pytest.raises(ValueError, match="larger than half the window"):
            m(torch.full((1, 1, 4, 30), 2.0), torch.ones(1, 1, 4, 30), sigma=0.1)
    with pytest.raises(ValueError, match="kernel_size must be odd"):
        Bilateral(kernel_size=4)
    with pytest.raises(ValueError, match="sigma_space"):
        Bilateral(sigma_space=0.0)
    with pytest.raises(ValueError, match="eps"):
        Guided(eps=-1.0)
    with pytest.raises(ValueError, match="guide must be"):
        Guided(guide="ir")
    with pytest.raises(ValueError, match="needs the amplitude"):
        JointBilateral()(x)
    with pytest.raises(ValueError, match="sigma must be a finite number >= 0"):
        Bilateral()(x, sigma=-1.0)
    # the joint filter's range kernel is on the amplitude, but sigma keeps the common rules
    a = torch.full_like(x[:1], 50.0) + torch.arange(12.0)
    for bad in (-1.0, math.nan):
        with pytest.raises(ValueError, match="sigma must be a finite number >= 0"):
            JointBilateral()(x[:1], a, sigma=bad)
    torch.testing.assert_close(JointBilateral()(x[:1], a, sigma=0.0), x[:1], atol=0, rtol=0)
    assert not torch.equal(JointBilateral()(x[:1], a, sigma=0.01), x[:1])
    with pytest.raises(ValueError, match="amplitude must have shape"):
        Guided()(x, torch.ones(2, 1, 4, 4))


@pytest.mark.parametrize(
    "fn", ["bilateral", "guided", "bm3d", "sliding_dct", "hypothesis_bilateral", "lpa_ici"]
)
def test_functional_forms_refuse_a_bad_noise_constant_as_the_modules_do(fn):
    x = 1.0 + 0.01 * torch.randn(1, 1, 24, 24, generator=torch.Generator().manual_seed(0))
    a = torch.full_like(x, 100.0)
    for bad in (-1.0, 0.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="k must be None or a finite number > 0"):
            getattr(denoise, fn)(x, a, k=bad)


def test_level_settings_are_checked_by_the_functions_too():
    x = 1.0 + 0.01 * torch.randn(1, 1, 24, 24, generator=torch.Generator().manual_seed(0))
    for f in (bilateral, guided):
        for kw in ({"ratio": 1.0}, {"ratio": 0.5}, {"max_levels": 0}):
            with pytest.raises(ValueError, match="ratio must be > 1 and max_levels >= 1"):
                f(x, sigma=0.01, **kw)
    with pytest.raises(ValueError, match="ratio must be > 1"):
        Bilateral(ratio=0.5)


def test_registry_names_get_and_errors():
    names = denoise.names()
    assert names[:2] == ["nlm", "bm3d"] and {"bilateral", "joint-bilateral", "guided"} <= set(names)
    assert isinstance(denoise.get("Joint_Bilateral"), JointBilateral)
    assert denoise.get("bm3d", step=4).step == 4
    assert denoise.get("non-local-means").__class__.__name__ == "NonLocalMeans"
    with pytest.raises(ValueError, match="unknown denoiser 'wiener'; choose one of"):
        denoise.get("wiener")
    with pytest.raises(ValueError, match=r"has no parameter\(s\) \['patch'\]"):
        denoise.get("bm3d", patch=3)
    with pytest.raises(ValueError, match="block_size"):
        denoise.get("bm3d", block_size=0)
    assert all(denoise.describe(n).startswith(n + ": ") for n in names)


def test_every_registered_denoiser_runs_the_common_interface():
    gt, amp, noisy = _frame(seed=3, size=(40, 48))
    holes = torch.zeros_like(gt, dtype=torch.bool)
    holes[..., 5:9, 7:12] = True
    x = torch.where(holes, torch.zeros_like(noisy), noisy)
    for name in denoise.names():
        m = denoise.get(name)
        for kw in ({"amplitude": amp}, {"amplitude": amp, "sigma": 0.05}):
            out = m(x, **kw)
            assert out.shape == x.shape and out.dtype == x.dtype, name
            assert bool((out[holes] == 0).all()) and bool(torch.isfinite(out).all()), name
        if name != "joint-bilateral":
            assert m(x).shape == x.shape, name
        if denoise.scriptable(name):
            s = torch.jit.script(m)
            torch.testing.assert_close(s(x, amp), m(x, amp), atol=0, rtol=0)
        else:
            with pytest.raises(Exception):  # noqa: B017 - kornia's functions are not scriptable
                torch.jit.script(m)
