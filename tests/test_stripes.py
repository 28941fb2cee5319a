"""estimate_stripes: finds periodic column/row patterns, their strength, and nothing in a clean scene."""

from __future__ import annotations

import math

import pytest
import torch

from tof_fpn_torch import estimate_stripes


def _frames(b=3, h=96, w=144, seed=0, noise=0.01, step=0.3):
    g = torch.Generator().manual_seed(seed)
    xx = torch.arange(w, dtype=torch.float64).expand(h, w)
    scene = 2.0 + 0.5 * torch.sin(xx / 25.0) + step * (xx > w / 2).double()
    return scene + noise * torch.randn(b, 1, h, w, generator=g, dtype=torch.float64)


def test_finds_paper_frequencies_columns():
    d = _frames()
    n = torch.arange(d.shape[-1], dtype=torch.float64)
    d = d + 0.02 * torch.cos(2 * math.pi / 3 * n + 0.3) + 0.01 * torch.cos(math.pi * n)
    est = estimate_stripes(d, torch.full_like(d, 40.0))
    cols = [c for c in est.components if c.orientation == "columns"]
    freqs = sorted(c.frequency for c in cols)
    assert len(freqs) == 2 and not [c for c in est.components if c.orientation == "rows"]
    assert abs(freqs[0] - 2 * math.pi / 3) < 2 * math.pi / d.shape[-1] / 4
    assert freqs[1] == math.pi
    by_f = {round(c.frequency, 1): c for c in cols}
    assert abs(by_f[round(math.pi, 1)].strength - 0.01) < 0.003
    assert abs(by_f[round(2 * math.pi / 3, 1)].strength - 0.02) < 0.006
    assert all(c.dim == -1 and 0.5 < c.confidence <= 1 for c in cols)
    assert est.notches() == tuple(freqs) and est.dims == (-1,)


def test_finds_other_frequency_rows():
    d = _frames(seed=1, step=0.0).transpose(-1, -2).contiguous()
    n = torch.arange(d.shape[-2], dtype=torch.float64).unsqueeze(-1)
    d = d + 0.02 * torch.cos(0.55 * math.pi * n)
    est = estimate_stripes(d)
    assert len(est.components) == 1
    c = est.components[0]
    assert c.orientation == "rows" and c.dim == -2
    assert abs(c.frequency - 0.55 * math.pi) < 0.02


def test_clean_scene_has_no_stripes():
    d = _frames(seed=2)
    d[0, 0, 10:20, 30:40] = float("nan")
    d[1, 0, 50:52, :] = 0.0
    assert estimate_stripes(d, torch.full_like(d, 100.0)).components == ()


def test_low_amplitude_pixels_weigh_more():
    # stripes only where the amplitude is low; strong noise where it is high
    d = _frames(seed=3, noise=0.0, step=0.0)
    g = torch.Generator().manual_seed(4)
    n = torch.arange(d.shape[-1], dtype=torch.float64)
    amp = torch.full_like(d, 1000.0)
    amp[..., :24, :] = 20.0
    d[..., :24, :] += 0.01 * torch.cos(2 * math.pi / 3 * n)
    d[..., 24:, :] += 0.05 * torch.randn(d[..., 24:, :].shape, generator=g, dtype=torch.float64)
    weighted = estimate_stripes(d, amp, false_alarm=0.999, min_stripe=0.0, max_components=100)
    plain = estimate_stripes(d, None, false_alarm=0.999, min_stripe=0.0, max_components=100)

    def snr(est):
        near = [
            c.snr_db
            for c in est.components
            if c.orientation == "columns" and abs(c.frequency - 2 * math.pi / 3) < 0.05
        ]
        return max(near, default=-math.inf)

    assert snr(weighted) > snr(plain) + 3.0


def test_errors():
    d = torch.ones(1, 1, 16, 16)
    with pytest.raises(ValueError, match="no valid pixel"):  # negative amplitude: all invalid
        estimate_stripes(d, -d)
    with pytest.raises(ValueError, match="same shape"):
        estimate_stripes(d, torch.ones(1, 1, 16, 15))
    with pytest.raises(ValueError, match="no valid pixel"):
        estimate_stripes(torch.zeros(1, 1, 16, 16))
    with pytest.raises(ValueError, match="orientations"):
        estimate_stripes(d, orientations=("diagonal",))
    with pytest.raises(ValueError, match="floating-point"):
        estimate_stripes(torch.ones(1, 1, 16, 16, dtype=torch.int32))
