"""Tests of tof_fpn_torch.denoise (non-local means and noise estimators). CPU, seeded, fast."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data
import torch
from scipy.ndimage import uniform_filter
from skimage.metrics import peak_signal_noise_ratio
from skimage.restoration import denoise_nl_means
from skimage.restoration import estimate_sigma as sk_estimate_sigma

from tof_fpn_torch.denoise import NonLocalMeans, estimate_noise_k, estimate_sigma, non_local_means
from tof_fpn_torch.denoise.nlm_core import reflect_pad as _reflect_pad


def t4(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a))[None, None]


def reference_nlm(img, s, d, h, sigma, valid=None, skimage_box=False):
    """Brute-force NLM over all (2d+1)^2 offsets with scipy.ndimage.uniform_filter (float64).

    ``skimage_box=True`` reproduces scikit-image's fast mode instead: the patch sum over the
    (s-1) x (s-1) box (row - s//2, row + s//2] x (col - s//2, col + s//2], divided by s^2,
    and weights set to 0 where that distance exceeds 5."""
    H, W = img.shape
    r = s // 2
    P = d + r + 1
    m = np.ones_like(img) if valid is None else valid.astype(float)
    x = np.where(m > 0, img, 0.0)
    xp = np.pad(x, P, mode="reflect")
    mp = np.pad(m, P, mode="reflect")
    num = np.zeros((H, W))
    den = np.zeros((H, W))
    inner = (slice(P, P + H), slice(P, P + W))
    for ty in range(-d, d + 1):
        for tx in range(-d, d + 1):
            sh = np.roll(xp, (-ty, -tx), (0, 1))
            msh = np.roll(mp, (-ty, -tx), (0, 1))
            mm = mp * msh
            if skimage_box:
                # (s-1)-box anchored at +1/2: uniform_filter of even size s-1 with origin -1
                box = uniform_filter(
                    (xp - sh) ** 2 - 2 * sigma**2, s - 1, mode="constant", origin=-1
                )
                dist = np.maximum(box * (s - 1) ** 2 / s**2, 0)[inner] / h**2
                w = np.where(dist > 5, 0.0, np.exp(-dist))
            else:
                D = uniform_filter(mm * (xp - sh) ** 2, s, mode="constant")[inner]
                N = uniform_filter(mm, s, mode="constant")[inner]
                msd = D / np.maximum(N, 1e-12)
                w = np.exp(-np.maximum(msd - 2 * sigma**2, 0) / h**2)
            num += w * (sh * msh)[inner]
            den += w * msh[inner]
    out = num / np.where(den > 0, den, 1)
    return np.where(m > 0, out, img)


def planar_scene(H, W, seed):
    """Piecewise-planar ToF-like scene: a tilted back wall and planar patches facing the camera
    at several depths (metres, in (0, 7.5]) with their own reflectance-driven amplitude."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:H, :W] / max(H, W)
    depth = 6.0 - 1.5 * yy + 0.5 * xx
    amp = np.full((H, W), 40.0)
    for _ in range(6):
        y0, x0 = rng.integers(0, H - 20), rng.integers(0, W - 20)
        hh, ww = rng.integers(15, H // 2), rng.integers(15, W // 2)
        z = rng.uniform(0.8, 5.0)
        gy, gx = rng.uniform(-1, 1, 2)
        sl = (slice(y0, y0 + hh), slice(x0, x0 + ww))
        depth[sl] = z + gy * yy[sl] + gx * xx[sl]
        amp[sl] = rng.uniform(30, 300)
    return depth, amp


# ---------------------------------------------------------------- reference implementations


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-6)])
def test_matches_bruteforce_reference(dtype, tol):
    rng = np.random.default_rng(0)
    img = rng.random((30, 37))
    img[5:20, 8:25] += 1.0
    noisy = img + 0.1 * rng.standard_normal(img.shape)
    ref = reference_nlm(noisy, 5, 3, 0.8 * 0.1, 0.1)
    out = non_local_means(
        t4(noisy).to(dtype), sigma=0.1, patch_size=5, patch_distance=3, signed=True
    )
    assert out.dtype == dtype
    np.testing.assert_allclose(out[0, 0].double().numpy(), ref, atol=tol, rtol=0)


def test_invalid_pixels_match_masked_reference_and_stay_invalid():
    rng = np.random.default_rng(1)
    img = 2.0 + rng.random((28, 33))
    valid = rng.random(img.shape) > 0.15
    noisy = np.where(valid, img + 0.1 * rng.standard_normal(img.shape), 0.0)
    ref = reference_nlm(noisy, 5, 3, 0.08, 0.1, valid)
    out = non_local_means(t4(noisy), sigma=0.1, patch_size=5, patch_distance=3)[0, 0].numpy()
    np.testing.assert_allclose(out, ref, atol=1e-12, rtol=0)
    assert np.all(out[~valid] == 0)
    # the value stored in an invalid pixel (0, NaN, or garbage marked NaN) changes nothing
    with_nan = np.where(valid, noisy, np.nan)
    out_nan = non_local_means(t4(with_nan), sigma=0.1, patch_size=5, patch_distance=3)[0, 0]
    assert torch.isnan(out_nan[torch.from_numpy(~valid)]).all()
    np.testing.assert_allclose(out_nan.numpy()[valid], out[valid], atol=1e-12, rtol=0)


def test_skimage_fast_mode_is_our_algorithm_with_its_offcentre_box():
    """Which skimage variant we match: with the (s-1)^2 off-centre box and cutoff of skimage's
    fast mode the brute-force reference reproduces skimage itself (up to its approximate exp);
    with the centred s^2 box it reproduces us (test above)."""
    rng = np.random.default_rng(2)
    img = rng.random((36, 44))
    img[10:30, 10:30] += 1.0
    s, d, sig = 5, 3, 0.2
    sk = denoise_nl_means(img, s, d, 0.8 * sig, fast_mode=True, sigma=sig)
    emul = reference_nlm(img, s, d, 0.8 * sig, sig, skimage_box=True)
    assert np.abs(emul - sk).max() < 1e-2
    ours = non_local_means(t4(img), sigma=sig, patch_size=s, patch_distance=d)[0, 0].numpy()
    assert np.abs(ours - sk).max() > 10 * np.abs(emul - sk).max()  # the box is what differs


def _psnr_pair(clean, noisy, sig, s, d, kernel, fast, data_range, signed=False):
    ours = non_local_means(
        t4(noisy), sigma=sig, patch_size=s, patch_distance=d, kernel=kernel, signed=signed
    )
    sk = denoise_nl_means(noisy, s, d, 0.8 * sig, fast_mode=fast, sigma=sig)
    return (
        peak_signal_noise_ratio(clean, ours[0, 0].numpy(), data_range=data_range),
        peak_signal_noise_ratio(clean, sk, data_range=data_range),
    )


@pytest.mark.parametrize("sig", [0.05, 0.1])
def test_psnr_camera_vs_skimage(sig):
    """Same patch size, window and h: box vs fast_mode=True, gaussian vs fast_mode=False."""
    cam = skimage.data.camera()[128:384, 128:384] / 255.0
    noisy = cam + sig * np.random.default_rng(3).standard_normal(cam.shape)
    for kernel, fast in (("box", True), ("gaussian", False)):
        p_ours, p_sk = _psnr_pair(cam, noisy, sig, 7, 5, kernel, fast, 1.0, signed=True)
        assert p_ours >= p_sk - 0.3, (kernel, p_ours, p_sk)
        assert p_ours > peak_signal_noise_ratio(cam, noisy, data_range=1.0) + 5


@pytest.mark.parametrize("sig", [0.1, 0.3])
def test_psnr_tof_scene_vs_skimage(sig):
    """Piecewise-planar depth: both kernels beat skimage's original (fast_mode=False) NLM; see
    docs/denoise.md for fast_mode=True, whose off-centre (s-1)^2 box scores higher here."""
    depth, _ = planar_scene(128, 160, seed=1)
    noisy = depth + sig * np.random.default_rng(4).standard_normal(depth.shape)
    for kernel in ("box", "gaussian"):
        p_ours, p_sk = _psnr_pair(depth, noisy, sig, 7, 10, kernel, False, 7.5)
        assert p_ours >= p_sk - 0.3, (kernel, p_ours, p_sk)
    assert p_ours > peak_signal_noise_ratio(depth, noisy, data_range=7.5) + 10


def test_reflect_pad_matches_numpy():
    x = torch.arange(3 * 4, dtype=torch.float64).reshape(1, 1, 3, 4)
    for pad in (1, 2, 3, 7):
        np.testing.assert_array_equal(
            _reflect_pad(x, pad)[0, 0].numpy(), np.pad(x[0, 0].numpy(), pad, mode="reflect")
        )
    one = torch.ones(1, 1, 1, 3)
    assert _reflect_pad(one, 2).shape == (1, 1, 5, 7)


def test_tiny_image_needs_repeated_reflection():
    rng = np.random.default_rng(5)
    tiny = rng.random((4, 5))
    out = non_local_means(t4(tiny), sigma=0.3, patch_size=5, patch_distance=3)[0, 0].numpy()
    np.testing.assert_allclose(out, reference_nlm(tiny, 5, 3, 0.24, 0.3), atol=1e-12, rtol=0)


# ---------------------------------------------------------------- noise levels


def test_estimate_sigma_matches_skimage():
    cam = skimage.data.camera() / 255.0
    rng = np.random.default_rng(6)
    for sig in (0.02, 0.08):
        noisy = cam + sig * rng.standard_normal(cam.shape)
        ours = float(estimate_sigma(t4(noisy)))
        assert ours == pytest.approx(sk_estimate_sigma(noisy), rel=0.01)
    # invalid pixels (zeros marked invalid) are ignored
    depth, _ = planar_scene(128, 160, seed=2)
    noisy = depth + 0.05 * rng.standard_normal(depth.shape)
    holes = rng.random(depth.shape) < 0.1
    noisy[holes] = 0.0
    est = float(estimate_sigma(t4(noisy), valid=t4(~holes)))
    assert est == pytest.approx(0.05, rel=0.1)
    assert float(estimate_sigma(t4(noisy))) > 2 * est  # without the mask the holes dominate


def test_amplitude_sets_noise_map_and_k_is_estimated():
    depth, amp = planar_scene(96, 120, seed=3)
    rng = np.random.default_rng(7)
    k = 4.0
    noisy = depth + k / amp * rng.standard_normal(depth.shape)
    k_hat = float(estimate_noise_k(t4(noisy), t4(amp)))
    assert k_hat == pytest.approx(k, rel=0.1)
    kw = dict(patch_size=5, patch_distance=5)
    with_k = non_local_means(t4(noisy), t4(amp), k=k, **kw)
    as_map = non_local_means(t4(noisy), sigma=t4(k / amp), **kw)
    torch.testing.assert_close(with_k, as_map, atol=1e-12, rtol=0)
    p = lambda o: peak_signal_noise_ratio(depth, o[0, 0].numpy(), data_range=7.5)  # noqa: E731
    p_amp = p(non_local_means(t4(noisy), t4(amp), **kw))
    p_scalar = p(non_local_means(t4(noisy), **kw))
    assert p_amp > p_scalar + 3  # the per-pixel level is what makes NLM work on ToF data


def test_constant_map_equals_scalar_with_and_without_holes():
    rng = np.random.default_rng(8)
    x = 1.0 + rng.random((2, 1, 20, 24))
    x[1, 0, 3:6, 4:9] = 0.0
    xt = torch.from_numpy(x)
    a = non_local_means(xt, sigma=0.2, patch_size=3, patch_distance=4)
    b = non_local_means(
        xt,
        sigma=torch.full((2, 1, 20, 24), 0.2, dtype=torch.float64),
        patch_size=3,
        patch_distance=4,
    )
    c = non_local_means(
        xt, sigma=torch.tensor([0.2, 0.2], dtype=torch.float64), patch_size=3, patch_distance=4
    )
    torch.testing.assert_close(a, b, atol=1e-12, rtol=0)
    torch.testing.assert_close(a, c, atol=0, rtol=0)
    kw = dict(patch_size=5, patch_distance=3, kernel="gaussian")
    torch.testing.assert_close(
        non_local_means(xt, sigma=0.2, **kw),
        non_local_means(xt, sigma=torch.full((2, 1, 20, 24), 0.2, dtype=torch.float64), **kw),
        atol=1e-12,
        rtol=0,
    )


# ---------------------------------------------------------------- module behaviour


def _inputs():
    g = torch.Generator().manual_seed(9)
    x = 2.0 + torch.rand(2, 1, 24, 30, generator=g, dtype=torch.float64)
    x[0, 0, 5, 5] = float("nan")
    x[1, 0, 10:12, 3:7] = 0.0
    amp = 20 + 200 * torch.rand(2, 1, 24, 30, generator=g, dtype=torch.float64)
    return x, amp


def test_torchscript_matches_eager():
    x, amp = _inputs()
    eager = NonLocalMeans(patch_size=5, patch_distance=4)
    scripted = torch.jit.script(eager)
    for kwargs in (
        {},
        {"sigma": 0.1},
        {"sigma": torch.full((2, 1, 24, 30), 0.1, dtype=torch.float64)},
        {"amplitude": amp},
    ):
        torch.testing.assert_close(scripted(x, **kwargs), eager(x, **kwargs), equal_nan=True)
    for eager in (NonLocalMeans(3, 2, k=5.0), NonLocalMeans(5, 3, kernel="gaussian")):
        scripted = torch.jit.script(eager)
        torch.testing.assert_close(scripted(x, amp), eager(x, amp), equal_nan=True)
        torch.testing.assert_close(scripted(x, sigma=0.1), eager(x, sigma=0.1), equal_nan=True)


def test_batch_channels_dtype_and_no_inplace():
    x, _ = _inputs()
    before = x.clone()
    nlm = NonLocalMeans(patch_size=3, patch_distance=3)
    out = nlm(x, sigma=0.1)
    torch.testing.assert_close(x, before, equal_nan=True)  # input untouched
    for b in range(2):  # batch items are independent
        torch.testing.assert_close(out[b : b + 1], nlm(x[b : b + 1], sigma=0.1), equal_nan=True)
    # two identical channels: the channel-mean distance equals the single-channel one
    out2 = nlm(torch.cat([x, x], 1), sigma=0.1)
    torch.testing.assert_close(out2[:, :1], out, equal_nan=True)
    torch.testing.assert_close(out2[:, 1:], out, equal_nan=True)
    half = nlm(x.half(), sigma=0.1)
    assert half.dtype == torch.float16
    # computed in float32 from the rounded input: within a few float16 ulps of the float64 result
    ref = nlm(x.half().double(), sigma=0.1)
    torch.testing.assert_close(half.double(), ref, rtol=2e-3, atol=0, equal_nan=True)


def test_zero_noise_and_zero_distance_leave_data_unchanged():
    x, _ = _inputs()
    torch.testing.assert_close(non_local_means(x, sigma=0.0), x, equal_nan=True)
    torch.testing.assert_close(non_local_means(x, sigma=0.3, patch_distance=0), x, equal_nan=True)


def test_real_adi_wall_crop(real_data):
    depth = real_data.adi_wall()[0][0, 0, 192:320, 192:320].numpy().copy()
    assert np.all(depth > 0)  # the crop is all valid: the holes below are ours
    depth[40:43, 50:60] = 0.0  # the camera's "no measurement" code
    depth[90, 17] = np.nan
    holes = ~(depth > 0)
    out = non_local_means(t4(depth), patch_size=5, patch_distance=5)[0, 0].numpy()
    assert np.all(out[depth == 0] == 0) and np.isnan(out[90, 17])
    assert np.all(np.isfinite(out[~holes]))
    # a near-flat screen in mm with little noise: the wavelet noise level drops, the surface
    # does not move
    assert float(estimate_sigma(t4(out), valid=t4(~holes))) < 0.9 * float(
        estimate_sigma(t4(depth), valid=t4(~holes))
    )
    assert np.abs(out - depth)[~holes].mean() < 1.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu():
    x, amp = _inputs()
    nlm = NonLocalMeans(patch_size=5, patch_distance=4)
    torch.testing.assert_close(
        nlm.cuda()(x.cuda(), amp.cuda()).cpu(), nlm.cpu()(x, amp), equal_nan=True
    )


# ---------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"patch_size": 4}, "odd"),
        ({"patch_size": 0}, "odd"),
        ({"patch_distance": -1}, "patch_distance"),
        ({"h": 0.0}, "h must"),
        ({"h": float("nan")}, "h must"),
        ({"k": -1.0}, "k must"),
        ({"kernel": "disk"}, "kernel must"),
    ],
)
def test_bad_parameters(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NonLocalMeans(**kwargs)
    with pytest.raises(ValueError, match=match):
        non_local_means(torch.ones(1, 1, 8, 8), sigma=0.1, **kwargs)


def test_bad_inputs():
    x = torch.ones(1, 1, 8, 8)
    nlm = NonLocalMeans(3, 2)
    with pytest.raises(ValueError, match="4 dimensions"):
        nlm(torch.ones(8, 8))
    with pytest.raises(ValueError, match="floating-point"):
        nlm(torch.ones(1, 1, 8, 8, dtype=torch.int32))
    # sigma and amplitude together: sigma sets the noise, the amplitude only its validity rule
    xr = 1.0 + 0.1 * torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(nlm(xr, torch.ones(1, 1, 8, 8), 0.1), nlm(xr, sigma=0.1))
    with pytest.raises(ValueError, match="amplitude must have shape"):
        nlm(x, torch.ones(1, 1, 8, 9))
    with pytest.raises(ValueError, match="amplitude must have 1 channel"):
        nlm(x, torch.ones(1, 2, 8, 8))
    with pytest.raises(ValueError, match="sigma must be a float"):
        nlm(x, sigma=torch.ones(1, 2, 8, 8))
    with pytest.raises(ValueError, match=">= 0"):
        nlm(x, sigma=-0.1)
    with pytest.raises(ValueError, match=">= 0"):
        nlm(x, sigma=torch.tensor([-0.1]))
    with pytest.raises(ValueError, match="valid pixel"):
        nlm(x, sigma=torch.full((1, 1, 8, 8), float("nan")))
    with pytest.raises(ValueError, match="patch_size must be an int"):
        NonLocalMeans(patch_size=5.0)
    with pytest.raises(ValueError, match="valid must"):
        estimate_sigma(x, valid=torch.ones(1, 1, 8, 8))


def test_sigma_as_int_or_numpy_scalar_is_a_number():
    """Rough edge: ``sigma=1`` (an int) or a NumPy scalar used to raise AttributeError."""
    g = torch.Generator().manual_seed(3)
    x = 2.0 + 0.1 * torch.randn(1, 1, 24, 24, generator=g)
    ref = non_local_means(x, sigma=1.0, patch_size=3, patch_distance=2)
    torch.testing.assert_close(non_local_means(x, sigma=1, patch_size=3, patch_distance=2), ref)
    out = non_local_means(x, sigma=np.float32(1.0), patch_size=3, patch_distance=2)
    torch.testing.assert_close(out, ref)
    with pytest.raises(ValueError, match="sigma must be a number, a tensor or None, got str"):
        non_local_means(x, sigma="0.1")
