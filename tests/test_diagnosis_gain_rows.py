"""The row member of the pixel gain: its closed form recovers weak rows and leaves a smooth
change along the rows and noise alone, and a gain of weak rows and pixel clusters (not the
catalogue's random gain per pixel) is named ``pixel_gain`` through it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tof_fpn_torch.diagnosis.terms.pixel_gain_rows import row_gains

H, W = 90, 120


def _rows(profile, seed, sd=0.004):
    gen = torch.Generator().manual_seed(seed)
    noise = sd * torch.randn(H, W, generator=gen, dtype=torch.float64)
    rel = profile.view(H, 1) + noise
    return rel, torch.full((H, W), sd * sd, dtype=torch.float64), torch.ones(H, W, dtype=bool)


def test_row_gains_recover_weak_rows_and_shrink_noise_to_zero():
    """Three rows at -3 %, -2 % and +1.5 % over pixel noise of 0.4 %: each within 0.1 % of its
    gain (a row's mean has sd 0.04 %), the others within 0.15 % of 0, about 3 effective
    parameters. Pure noise: every gain under 0.02 %, under 3 effective parameters. A gain in
    every row: found row by row. Checked against the rows' means computed with NumPy."""
    prof = torch.zeros(H, dtype=torch.float64)
    prof[[10, 47, 80]] = torch.tensor([-0.03, -0.02, 0.015], dtype=torch.float64)
    rel, var, ok = _rows(prof, 1)
    g, dof = row_gains(rel, var, ok)
    means = rel.numpy().mean(1)
    assert np.allclose(g.numpy()[[10, 47, 80]], means[[10, 47, 80]], atol=2e-3)
    assert float((g[[10, 47, 80]] - prof[[10, 47, 80]]).abs().max()) < 1e-3
    rest = torch.ones(H, dtype=torch.bool)
    rest[[10, 47, 80]] = False
    assert float(g[rest].abs().max()) < 1.5e-3
    assert 3 <= dof < 5  # three lines: three parameters, not one per row
    g0, dof0 = row_gains(*_rows(torch.zeros(H, dtype=torch.float64), 2))
    assert float(g0.abs().max()) < 2e-4 and dof0 < 3
    # a gain in every row (the Gaussian random effect): nearly a parameter per row
    gen = torch.Generator().manual_seed(4)
    every = 0.003 * torch.randn(H, generator=gen, dtype=torch.float64)
    g, dof = row_gains(*_rows(every, 5))
    assert dof > 0.8 * H and float(torch.corrcoef(torch.stack([g, every]))[0, 1]) > 0.8


def test_row_gains_leave_a_smooth_change_along_the_rows():
    """A light falling by 20 % smoothly from the top to the bottom row (a vignette, the scene's
    light) is not a row pattern: the gains stay under 0.1 %; with one weak row on top of it,
    that row is found."""
    y = torch.arange(H, dtype=torch.float64)
    smooth = -0.2 * (y / (H - 1)) ** 2
    g, _ = row_gains(*_rows(smooth, 3))
    assert float(g.abs().max()) < 1e-3
    bump = smooth.clone()
    bump[40] -= 0.03
    g, _ = row_gains(*_rows(bump, 3))
    assert float(g[40]) < -0.025 and int(g.argmin()) == 40


@pytest.mark.slow
def test_weak_rows_and_clusters_are_named_pixel_gain_through_the_member():
    """Two weak rows and four small clusters at 4 % less light (no random gain per pixel) are
    named ``pixel_gain`` alone, through the row member, whose largest row loss is the planted
    one's."""
    from test_diagnosis import H as h
    from test_diagnosis import W as w
    from test_diagnosis import _recording

    from tof_fpn_torch.diagnosis import diagnose
    from tof_fpn_torch.sim import PixelGain

    rng = np.random.default_rng(9)
    weak = np.zeros((h, w), bool)
    weak[rng.choice(h, 2, replace=False)] = True
    yy, xx = np.mgrid[0:h, 0:w]
    for _ in range(4):
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        weak |= (yy - cy) ** 2 + (xx - cx) ** 2 <= 2.5**2
    g = torch.from_numpy(np.where(weak, 0.96, 1.0))
    rec, sd = _recording(PixelGain(gain_map=g), seed=6)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.report["verdict"] == ["pixel_gain"], diag.report["effects"]
    eff = diag.report["effects"][0]
    assert "pixel_gain_rows" in eff["terms"]
    assert 3.0 < eff["params"]["largest_row_loss_percent"] < 5.0
