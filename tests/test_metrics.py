"""Metrics: PSNR (eq. 9) vs scikit-image, RMSE/MAE vs NumPy, masks, LOW / IMP shares."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.ndimage import median_filter
from skimage.metrics import peak_signal_noise_ratio

from tof_fpn_torch import metrics as M
from tof_fpn_torch.runtime import valid_mask
from tof_fpn_torch.sim import Camera, Simulation, synthetic_scene


def _pair(seed=0, shape=(3, 1, 20, 24)):
    g = torch.Generator().manual_seed(seed)
    gt = 0.5 + 7 * torch.rand(shape, generator=g, dtype=torch.float64)
    pred = gt + 0.2 * torch.randn(shape, generator=g, dtype=torch.float64)
    return pred, gt


def test_psnr_matches_skimage():
    pred, gt = _pair()
    got = M.psnr(pred, gt)
    for b in range(3):
        want = peak_signal_noise_ratio(gt[b].numpy(), pred[b].numpy(), data_range=7.5)
        assert abs(float(got[b]) - want) < 1e-9
    # eq. (9) form
    mse = ((pred - gt) ** 2).flatten(1).mean(1)
    torch.testing.assert_close(got, 20 * torch.log10(7.5 / torch.sqrt(mse)))


def test_rmse_mae_match_numpy_and_batch_is_per_image():
    pred, gt = _pair(1)
    e = (pred - gt).numpy().reshape(3, -1)
    np.testing.assert_allclose(M.rmse(pred, gt).numpy(), np.sqrt((e**2).mean(1)), rtol=1e-12)
    np.testing.assert_allclose(M.mae(pred, gt).numpy(), np.abs(e).mean(1), rtol=1e-12)
    torch.testing.assert_close(M.psnr(pred[1:2], gt[1:2]), M.psnr(pred, gt)[1:2])


def test_invalid_target_pixels_are_excluded_and_masks_combine():
    pred, gt = _pair(2, (1, 1, 10, 10))
    gt2 = gt.clone()
    gt2[0, 0, :3] = float("nan")
    gt2[0, 0, 3, :5] = 0.0
    keep = valid_mask(gt2)
    e = (pred - gt)[keep].numpy()
    np.testing.assert_allclose(float(M.rmse(pred, gt2)), np.sqrt((e**2).mean()), rtol=1e-12)
    user = torch.zeros_like(keep)
    user[0, 0, 5:] = True
    e2 = (pred - gt)[keep & user].numpy()
    np.testing.assert_allclose(float(M.mae(pred, gt2, user)), np.abs(e2).mean(), rtol=1e-12)


def test_metric_errors():
    pred, gt = _pair(3, (1, 1, 6, 6))
    bad = pred.clone()
    bad[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN/inf"):
        M.psnr(bad, gt)
    # excluding it explicitly works
    assert torch.isfinite(M.psnr(bad, gt, valid_mask(bad))).all()
    with pytest.raises(ValueError, match="no valid pixel"):
        M.rmse(pred, gt, torch.zeros_like(gt, dtype=torch.bool))
    with pytest.raises(ValueError, match="same shape"):
        M.mae(pred, gt[..., :3])
    with pytest.raises(ValueError, match=r"\(B, 1, H, W\)"):
        M.psnr(pred[0], gt[0])
    with pytest.raises(ValueError, match="d_max"):
        M.psnr(pred, gt, d_max=0.0)


def test_low_sensing_fraction():
    g = torch.Generator().manual_seed(5)
    amp = 600 * torch.rand((2, 1, 30, 30), generator=g)
    amp[0, 0, 0, 0] = float("nan")
    want = ((amp < 300) | torch.isnan(amp)).flatten(1).double().mean(1)
    torch.testing.assert_close(M.low_sensing_fraction(amp).double(), want)


def test_impulsive_mask_finds_spikes_and_median_matches_scipy():
    g = torch.Generator().manual_seed(6)
    yy, xx = torch.meshgrid(torch.arange(40.0), torch.arange(50.0), indexing="ij")
    depth = (2 + 0.02 * xx + 0.01 * yy).view(1, 1, 40, 50).double()
    med = M._median3x3(depth)
    np.testing.assert_allclose(
        med[0, 0].numpy(), median_filter(depth[0, 0].numpy(), 3, mode="nearest")
    )
    spikes = torch.rand(depth.shape, generator=g) < 0.03
    noisy = torch.where(spikes, depth + 3.0, depth)
    noisy[0, 0, 0, 0] = 0.0  # an invalid pixel is impulsive too
    expected = spikes.clone()
    expected[0, 0, 0, 0] = True
    got = M.impulsive_mask(noisy)
    assert torch.equal(got, expected)
    assert torch.equal(M.impulsive_mask(noisy, reference=depth), expected)
    frac = M.impulsive_fraction(noisy)
    assert abs(float(frac) - float(expected.double().mean())) < 1e-12
    stats = M.sensing_stats(noisy, torch.full_like(noisy, 100.0), reference=depth)
    assert float(stats["low"]) == 100.0 and abs(float(stats["imp"]) - 100 * float(frac)) < 1e-9


def test_imp_share_of_simulated_capture():
    scene = synthetic_scene(64, 64, seed=2)
    ref = scene.depth.expand(2, 1, 64, 64)
    sim = Simulation(Camera(integration_time=2e-3))
    base = sim.run(scene, frames=2, seed=3)  # noise + phase wrapping near 7.49 m: some IMP already
    sim.set_parameters(**{"impulsive.rate": 0.05, "impulsive.mode": "dead"})
    out = sim.run(scene, frames=2, seed=3)
    imp = M.impulsive_mask(out.depth, reference=ref, threshold=1.0)
    assert bool(imp[out.impulsive].all())  # every injected pixel is found
    added = M.impulsive_fraction(out.depth, ref, 1.0) - M.impulsive_fraction(base.depth, ref, 1.0)
    injected = out.impulsive.flatten(1).double().mean(1)
    base_imp = M.impulsive_mask(base.depth, reference=ref, threshold=1.0)
    overlap = (base_imp & out.impulsive).flatten(1).double().mean(1)
    torch.testing.assert_close(added.double(), injected - overlap, rtol=0, atol=1e-6)
    assert abs(float(injected.mean()) - 0.05) < 0.01


def test_metrics_torchscript_matches_eager():
    pred, gt = _pair(7)
    mask = gt > 2.0
    for fn in (M.psnr, M.rmse, M.mae, M.mse):
        torch.testing.assert_close(torch.jit.script(fn)(pred, gt, mask), fn(pred, gt, mask))
    amp = 400 * torch.rand_like(gt)
    torch.testing.assert_close(
        torch.jit.script(M.low_sensing_fraction)(amp, 300.0, None), M.low_sensing_fraction(amp)
    )
    torch.testing.assert_close(
        torch.jit.script(M.impulsive_mask)(pred, None, 0.5), M.impulsive_mask(pred)
    )
