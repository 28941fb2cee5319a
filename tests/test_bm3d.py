"""Tests of tof_fpn_torch.denoise.BM3D against the ``bm3d`` package (Makinen, Azzari, Foi).

CPU, seeded, small images (the package takes ~1 s per 160 x 160 image here); the 512 x 512 and
424 x 512 figures are in docs/denoise.md (benchmarks/bench_denoise.py).
"""

from __future__ import annotations

import math

import bm3d as bm3d_pkg
import numpy as np
import pytest
import pywt
import skimage.data
import torch
from skimage.metrics import peak_signal_noise_ratio

from tof_fpn_torch import constants as K
from tof_fpn_torch.denoise import BM3D, bm3d
from tof_fpn_torch.denoise.bm3d import psd_block_covariance
from tof_fpn_torch.denoise.bm3d_core import _haar, _haar_matrix, bior15_matrix, dct_matrix
from tof_fpn_torch.denoise.bm3d_match import match
from tof_fpn_torch.sim import planar_scene, synthetic_scene

if not hasattr(np, "trapz"):  # the bm3d package's PSD path calls np.trapz (removed in NumPy 2)
    setattr(np, "trapz", np.trapezoid)  # noqa: B010


@pytest.fixture(autouse=True)
def _one_thread():
    """One torch thread: the results do not depend on it, and on a shared 2-core machine two
    threads make each of BM3D's parallel regions wait for a busy core (10x slower here)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def t4(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))[None, None]


def _profile() -> bm3d_pkg.BM3DProfile:
    p = bm3d_pkg.BM3DProfile()
    p.num_threads = 1  # deterministic
    return p


def _gray(name: str) -> np.ndarray:
    img = getattr(skimage.data, name)().astype(np.float64) / 255.0
    return img.mean(2) if img.ndim == 3 else img


def test_bior15_matrix_is_pywt_periodised_wavedec():
    n = 8
    ref = np.zeros((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = 1.0
        with pytest.warns(UserWarning):  # pywt: "level 3 too high" (boundary effects expected)
            ref[:, i] = np.hstack(pywt.wavedec(e, "bior1.5", mode="periodization", level=3))
    got = bior15_matrix(n, torch.float64, torch.device("cpu")).numpy()
    np.testing.assert_allclose(got, ref, atol=1e-12)


def test_dct_and_haar_are_orthonormal():
    d = dct_matrix(8, torch.float64, torch.device("cpu"))
    torch.testing.assert_close(d @ d.t(), torch.eye(8, dtype=torch.float64))
    g = torch.Generator().manual_seed(0)
    for m in (1, 2, 8, 32):
        x = torch.randn(3, m, 5, generator=g, dtype=torch.float64)
        y = _haar(x, False)
        torch.testing.assert_close(y.square().sum(1), x.square().sum(1))  # energy kept
        torch.testing.assert_close(_haar(y, True), x)
        torch.testing.assert_close(y[:, 0], x.sum(1) / math.sqrt(m))  # first row: the mean


def test_haar_matrix_is_the_haar_transform():
    g = torch.Generator().manual_seed(1)
    for m in (1, 2, 16, 32):
        x = torch.randn(3, m, 5, generator=g, dtype=torch.float64)
        h = _haar_matrix(m, torch.float64, torch.device("cpu"))
        torch.testing.assert_close(torch.matmul(h, x), _haar(x, False))
        torch.testing.assert_close(h @ h.t(), torch.eye(m, dtype=torch.float64))


@pytest.mark.parametrize(
    ("shape", "n", "step", "radius", "n2"),
    [((23, 29), 4, 2, 5, 8), ((20, 17), 8, 3, 12, 16), ((14, 30), 3, 1, 2, 32)],
)
def test_pixel_matching_is_exact(shape, n, step, radius, n2):
    """The n2 nearest blocks of every reference in its window (clipped to the image), nearest
    first, the reference itself first: against a brute-force search."""
    g = torch.Generator().manual_seed(2)
    x = torch.rand(shape, generator=g, dtype=torch.float64)
    dist, idx = match(x, x[:0], n * n, n, step, radius, 4, n2)
    H, W = shape
    Hc, Wc = H - n + 1, W - n + 1
    blocks = x.unfold(0, n, 1).unfold(1, n, 1).reshape(Hc, Wc, n * n)
    refs = [(y, x_) for y in range(0, Hc, step) for x_ in range(0, Wc, step)]
    assert dist.shape[0] == len(refs)
    for i, (ry, rx) in enumerate(refs):
        cands = [
            (float((blocks[ry, rx] - blocks[cy, cx]).square().sum()), cy * Wc + cx)
            for cy in range(max(0, ry - radius), min(Hc, ry + radius + 1))
            for cx in range(max(0, rx - radius), min(Wc, rx + radius + 1))
        ]
        cands.sort()
        k = min(n2, len(cands))
        got = dist[i, :k]
        torch.testing.assert_close(got, torch.tensor([c[0] for c in cands[:k]]).to(got))
        assert idx[i, 0] == ry * Wc + rx and dist[i, 0] == 0.0
        assert idx[i, :k].tolist() == [c[1] for c in cands[:k]]
        assert bool(torch.isinf(dist[i, k:]).all())


@pytest.mark.parametrize(
    ("name", "crop"), [("camera", (slice(96, 256), slice(160, 320))), ("astronaut", None)]
)
def test_within_half_db_of_the_bm3d_package_natural(name, crop):
    img = _gray(name)
    img = img[crop] if crop else img[64:224, 192:352]
    s = 25.0 / 255.0
    noisy = img + s * np.random.default_rng(1).standard_normal(img.shape)
    ref = bm3d_pkg.bm3d(noisy, s, profile=_profile())
    ours = bm3d(t4(noisy), sigma=s, signed=True)[0, 0].double().numpy()
    p_ref = peak_signal_noise_ratio(img, ref, data_range=1.0)
    p_ours = peak_signal_noise_ratio(img, ours, data_range=1.0)
    assert p_ours > peak_signal_noise_ratio(img, noisy, data_range=1.0) + 6.0
    assert p_ours > p_ref - 0.5, (p_ours, p_ref)


def test_within_half_db_of_the_bm3d_package_tof_scene():
    """The paper's synthetic ToF scene (Fig. 7 kind), depth in metres, sigma 0.1 m."""
    gt = synthetic_scene(128, 160, seed=3).depth[0, 0].double().numpy()
    s = 0.1
    noisy = gt + s * np.random.default_rng(2).standard_normal(gt.shape)
    ref = bm3d_pkg.bm3d(noisy, s, profile=_profile())
    ours = bm3d(t4(noisy), sigma=s)[0, 0].double().numpy()
    p_ref = peak_signal_noise_ratio(gt, ref, data_range=K.D_MAX)
    p_ours = peak_signal_noise_ratio(gt, ours, data_range=K.D_MAX)
    assert p_ours > p_ref - 0.5, (p_ours, p_ref)


def test_coloured_noise_psd():
    """Correlated noise: the PSD path uses the exact coefficient variances (better than the
    white-noise assumption at the same pixel variance) and is close to the package's PSD path."""
    img = _gray("camera")[128:288, 192:352]
    h, w = img.shape
    kern = np.zeros((h, w))
    kern[0, 0], kern[0, 1], kern[1, 0] = 1.0, 0.8, 0.5
    rng = np.random.default_rng(3)
    white = 0.05 * rng.standard_normal((h, w))
    noise = np.real(np.fft.ifft2(np.fft.fft2(white) * np.fft.fft2(kern)))
    psd = np.abs(np.fft.fft2(kern)) ** 2 * (h * w) * 0.05**2
    noisy = img + noise
    p = {}
    ref = bm3d_pkg.bm3d(noisy, psd, profile=_profile())
    p["pkg"] = peak_signal_noise_ratio(img, ref, data_range=1.0)
    ours = bm3d(t4(noisy), psd=torch.from_numpy(psd), signed=True)[0, 0].double().numpy()
    p["psd"] = peak_signal_noise_ratio(img, ours, data_range=1.0)
    white_sigma = float(np.sqrt(psd.mean() / (h * w)))
    ours_w = bm3d(t4(noisy), sigma=white_sigma, signed=True)[0, 0].double().numpy()
    p["white"] = peak_signal_noise_ratio(img, ours_w, data_range=1.0)
    assert p["psd"] > p["white"] + 0.5, p
    assert p["psd"] > p["pkg"] - 1.0, p


def test_psd_of_white_noise_equals_sigma():
    psd = torch.full((32, 40), 32 * 40 * 0.05**2, dtype=torch.float64)
    cov, var = psd_block_covariance(psd, 8)
    assert math.isclose(var, 0.05**2, rel_tol=1e-12)
    torch.testing.assert_close(cov, torch.eye(64, dtype=torch.float64))
    x = t4(synthetic_scene(48, 56, seed=1).depth[0, 0].numpy())
    x = x + 0.05 * torch.randn(x.shape, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(bm3d(x, psd=psd), bm3d(x, sigma=0.05), atol=1e-5, rtol=0)


def _tof(seed: int = 0, size: tuple[int, int] = (64, 80)):
    scene = synthetic_scene(*size, seed=seed)
    g = torch.Generator().manual_seed(100 + seed)
    amp = scene.amplitude.clamp_min(20.0)
    noisy = scene.depth + (4.0 / amp) * torch.randn(scene.depth.shape, generator=g)
    return scene.depth, amp, noisy


def test_torchscript_equals_eager():
    _, amp, noisy = _tof()
    m = BM3D(search_radius=6)
    s = torch.jit.script(m)
    sig_map = torch.full_like(noisy, 0.03)
    for kw in ({}, {"sigma": 0.03}, {"sigma": sig_map}, {"amplitude": amp}):
        torch.testing.assert_close(s(noisy, **kw), m(noisy, **kw), atol=0, rtol=0)
    psd = torch.full((16, 16), 256 * 0.03**2, dtype=torch.float64)
    torch.testing.assert_close(s(noisy, psd=psd), m(noisy, psd=psd), atol=0, rtol=0)


def test_constant_map_equals_scalar_and_batch_is_independent():
    _, _, noisy = _tof()
    other = _tof(seed=1)[2]
    m = BM3D(search_radius=6)
    a = m(noisy, sigma=0.05)
    torch.testing.assert_close(m(noisy, sigma=torch.full_like(noisy, 0.05)), a)
    both = m(torch.cat([noisy, other]), sigma=0.05)
    torch.testing.assert_close(both[:1], a)
    torch.testing.assert_close(both[1:], m(other, sigma=0.05))


def test_amplitude_noise_law_beats_a_scalar_sigma():
    gt, amp, noisy = _tof(size=(96, 112))
    m = BM3D(search_radius=8)
    p_amp = float(10 * torch.log10(K.D_MAX**2 / (m(noisy, amp) - gt).square().mean()))
    p_est = float(10 * torch.log10(K.D_MAX**2 / (m(noisy) - gt).square().mean()))
    p_in = float(10 * torch.log10(K.D_MAX**2 / (noisy - gt).square().mean()))
    assert p_amp > p_est + 1.0 and p_est > p_in, (p_in, p_est, p_amp)


def test_invalid_pixels_are_returned_unchanged_and_do_not_leak():
    gt = synthetic_scene(64, 80, seed=0).depth
    g = torch.Generator().manual_seed(5)
    noisy = gt + 0.05 * torch.randn(gt.shape, generator=g)
    holes = torch.rand(noisy.shape, generator=g) < 0.1
    holes[..., 20:30, 30:45] = True  # and a large hole
    zero = torch.where(holes, torch.zeros_like(noisy), noisy)
    nan = torch.where(holes, torch.full_like(noisy, math.nan), noisy)
    m = BM3D(search_radius=6)
    out_zero, out_nan = m(zero, sigma=0.05), m(nan, sigma=0.05)
    assert bool((out_zero[holes] == 0).all()) and bool(out_nan[holes].isnan().all())
    torch.testing.assert_close(out_zero[~holes], out_nan[~holes], atol=0, rtol=0)
    assert bool(torch.isfinite(out_nan[~holes]).all())
    err_in = float((noisy - gt)[~holes].square().mean())
    err_full = float((m(noisy, sigma=0.05) - gt)[~holes].square().mean())  # without holes
    err_holes = float((out_zero - gt)[~holes].square().mean())
    # the zeros taken as data (signed=True): the holes bleed into their neighbours
    err_data = float(
        (bm3d(zero, sigma=0.05, search_radius=6, signed=True) - gt)[~holes].square().mean()
    )
    errs = (err_in, err_full, err_holes, err_data)
    assert err_holes < 0.6 * err_in and err_holes < 1.6 * err_full, errs
    assert err_holes < 0.7 * err_data, errs


def test_degenerate_inputs_documented_behaviour():
    m = BM3D(search_radius=4)
    x = 1.0 + 0.01 * torch.randn(2, 1, 16, 16, generator=torch.Generator().manual_seed(0))
    x[1] = 0.0  # an all-invalid frame: returned unchanged
    out = m(x, sigma=0.01)
    assert bool((out[1] == 0).all()) and not torch.equal(out[0], x[0])
    torch.testing.assert_close(m(x, sigma=0.0), x, atol=0, rtol=0)  # no noise: unchanged
    flat = torch.full((1, 1, 16, 16), 2.0)
    torch.testing.assert_close(m(flat), flat)  # estimated sigma 0: unchanged
    out8 = m(x[:1, :, :8, :8], sigma=0.01)  # exactly one block
    assert out8.shape == (1, 1, 8, 8) and bool(torch.isfinite(out8).all())
    h = m(x[:1].double(), sigma=0.01)
    assert h.dtype == torch.float64
    assert m(x[:1].half(), sigma=0.01).dtype == torch.float16


def test_bad_input_errors():
    m = BM3D()
    x = torch.ones(1, 1, 16, 16)
    with pytest.raises(ValueError, match="at least block_size"):
        m(torch.ones(1, 1, 7, 16), sigma=0.1)
    with pytest.raises(ValueError, match="sigma must be a finite number >= 0"):
        m(x, sigma=-0.1)
    with pytest.raises(ValueError, match="sigma must be a finite number >= 0"):
        m(x, sigma=math.nan)
    with pytest.raises(ValueError, match="finite and >= 0 at every valid pixel"):
        m(x, sigma=torch.full_like(x, -1.0))
    with pytest.raises(ValueError, match="sigma must be a number"):
        m(x, sigma="0.1")
    with pytest.raises(ValueError, match="psd describes the noise"):
        m(x, sigma=0.1, psd=torch.ones(16, 16))
    with pytest.raises(ValueError, match="psd must be finite"):
        m(x, psd=torch.zeros(16, 16))
    with pytest.raises(ValueError, match="at least block_size"):
        m(x, psd=torch.ones(4, 16))
    with pytest.raises(ValueError, match=r"\(B, C, H, W\)"):
        m(torch.ones(16, 16), sigma=0.1)
    with pytest.raises(ValueError, match="amplitude must have shape"):
        m(x, torch.ones(1, 1, 8, 8))
    for kw, msg in (
        ({"block_size": 1}, "block_size"),
        ({"step": 0}, "step"),
        ({"search_radius": -1}, "search_radius"),
        ({"max_blocks": (12, 32)}, "powers of two"),
        ({"tau": (0.0, 1.0)}, "tau"),
        ({"lam": 0.0}, "lam"),
        ({"mu2": -1.0}, "mu2"),
        ({"features_wiener": 10}, "features_wiener"),
        ({"transform_ht": "haar"}, "transform_ht"),
        ({"block_size": 6, "features_wiener": 36}, "power-of-two"),
        ({"k": 0.0}, "k must be"),
    ):
        with pytest.raises(ValueError, match=msg):
            BM3D(**kw)


def test_planar_scene_documented_gap():
    """Large flat boards: the package's 39 x 39 search averages more blocks than our default
    25 x 25 window; ``max_blocks=(32, 64)`` closes the gap (docs/denoise.md)."""
    gt = planar_scene(96, 112, seed=1).depth[0, 0].double().numpy()
    noisy = gt + 0.1 * np.random.default_rng(4).standard_normal(gt.shape)
    x = t4(noisy)
    p = {
        "default": bm3d(x, sigma=0.1)[0, 0].double().numpy(),
        "big": bm3d(x, sigma=0.1, max_blocks=(32, 64))[0, 0].double().numpy(),
        "pkg": bm3d_pkg.bm3d(noisy, 0.1, profile=_profile()),
    }
    p = {k: peak_signal_noise_ratio(gt, v, data_range=K.D_MAX) for k, v in p.items()}
    assert p["big"] > p["default"] and p["big"] > p["pkg"] - 0.5, p
