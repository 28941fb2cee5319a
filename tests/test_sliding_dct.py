"""Tests of tof_fpn_torch.denoise.SlidingDCT: against a brute-force SciPy reference (every window
transformed by ``scipy.fft.dctn``), TorchScript, holes, bad input. CPU, seeded, small images."""

from __future__ import annotations

import math

import numpy as np
import pytest
import skimage.data
import torch
from scipy.fft import dctn, idctn
from skimage.metrics import peak_signal_noise_ratio

from tof_fpn_torch.denoise import SlidingDCT, sliding_dct
from tof_fpn_torch.sim import synthetic_scene


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def reference(img: np.ndarray, sigma: float, n: int = 8, step: int = 1, lam: float = 2.7):
    """Every n x n window (grid ``step``, last row / column included): DCT, hard threshold at
    lam * sigma (DC kept), inverse; average with weights 1 / (sigma^2 N_kept)."""
    H, W = img.shape
    num = np.zeros((H, W))
    den = np.zeros((H, W))
    ys = sorted(set(range(0, H - n + 1, step)) | {H - n})
    xs = sorted(set(range(0, W - n + 1, step)) | {W - n})
    for y in ys:
        for x in xs:
            c = dctn(img[y : y + n, x : x + n], norm="ortho")
            keep = np.abs(c) > lam * sigma
            keep[0, 0] = True
            w = 1.0 / (sigma**2 * keep.sum())
            num[y : y + n, x : x + n] += w * idctn(c * keep, norm="ortho")
            den[y : y + n, x : x + n] += w
    return num / den


def test_equals_bruteforce_scipy_reference():
    g = np.random.default_rng(0)
    img = synthetic_scene(26, 30, seed=1).depth[0, 0].double().numpy()
    noisy = img + 0.05 * g.standard_normal(img.shape)
    x = torch.from_numpy(noisy)[None, None]
    ours = sliding_dct(x, sigma=0.05)[0, 0].numpy()
    np.testing.assert_allclose(ours, reference(noisy, 0.05), atol=1e-10)
    # a grid of windows: our grid ends on the last row / column by reflect-padding the image,
    # which the reference emulates by its extra last window only where the grid fits
    ours4 = sliding_dct(x[..., :24, :28], sigma=0.05, step=4)[0, 0].numpy()
    np.testing.assert_allclose(ours4, reference(noisy[:24, :28], 0.05, step=4), atol=1e-10)


def test_natural_image_quality_and_torchscript():
    img = skimage.data.camera()[128:288, 160:320].astype(np.float64) / 255.0
    s = 25.0 / 255.0
    noisy = img + s * np.random.default_rng(1).standard_normal(img.shape)
    x = torch.from_numpy(noisy).float()[None, None]
    m = SlidingDCT(signed=True)
    out = m(x, sigma=s)
    p_in = peak_signal_noise_ratio(img, noisy, data_range=1.0)
    p_out = peak_signal_noise_ratio(img, out[0, 0].double().numpy(), data_range=1.0)
    assert p_out > p_in + 6.0, (p_in, p_out)
    sm = torch.jit.script(m)
    torch.testing.assert_close(sm(x, sigma=s), out, atol=0, rtol=0)
    torch.testing.assert_close(sm(x), m(x), atol=0, rtol=0)
    amp = torch.full_like(x, 100.0)
    torch.testing.assert_close(sm(x, amp), m(x, amp), atol=0, rtol=0)


def test_holes_unchanged_and_bad_input():
    gt = synthetic_scene(40, 48, seed=2).depth
    g = torch.Generator().manual_seed(0)
    noisy = gt + 0.05 * torch.randn(gt.shape, generator=g)
    holes = torch.rand(gt.shape, generator=g) < 0.1
    x = torch.where(holes, torch.full_like(noisy, math.nan), noisy)
    out = SlidingDCT()(x, sigma=0.05)
    assert bool(out[holes].isnan().all()) and bool(torch.isfinite(out[~holes]).all())
    assert float((out - gt)[~holes].square().mean()) < 0.75 * float(
        (noisy - gt)[~holes].square().mean()
    )
    torch.testing.assert_close(SlidingDCT()(noisy, sigma=0.0), noisy, atol=0, rtol=0)
    allbad = torch.zeros(1, 1, 16, 16)
    torch.testing.assert_close(SlidingDCT()(allbad, sigma=0.1), allbad)
    with pytest.raises(ValueError, match="at least block_size"):
        SlidingDCT()(torch.ones(1, 1, 7, 20), sigma=0.1)
    with pytest.raises(ValueError, match="sigma must be a finite number >= 0"):
        SlidingDCT()(noisy, sigma=-1.0)
    for kw, msg in (
        ({"step": 9}, "step"),
        ({"lam": 0.0}, "lam"),
        ({"block_size": 1}, "block_size"),
    ):
        with pytest.raises(ValueError, match=msg):
            SlidingDCT(**kw)
