"""The sparse member of the pixel gain: its likelihood is the scale mixture (checked against
SciPy), the simulator's gain sits on the stated share, and weak rows and clusters (two gain
levels, not the member's Gaussian) are named ``pixel_gain`` through it."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.stats import norm

from tof_fpn_torch.diagnosis.likelihood import _gauss_ss
from tof_fpn_torch.sim import PixelGain


def test_mixture_nll_matches_scipy():
    """With ``mix = (s, sd)`` the mean's part of the NLL is ``-log[(1 - s) N(m; mu, v_m) +
    s N(m; mu, v_m + sd^2)]`` (SciPy's normal pdf), the spread's part unchanged."""
    rng = np.random.default_rng(3)
    p = 50
    n = torch.tensor(rng.integers(2, 30, p), dtype=torch.float64)
    mu = torch.tensor(rng.uniform(100, 900, p))
    sd = torch.tensor(rng.uniform(2, 9, p))
    m = mu + torch.tensor(rng.standard_normal(p)) * sd / n.sqrt() * 3
    m2 = (n - 1) * sd**2 * torch.tensor(rng.uniform(0.5, 1.5, p))
    tau, share, extra = 0.7, 0.08, 0.03 * mu
    got = float(_gauss_ss(n, m, m2, mu, sd, tau, None, (share, extra)))
    vm = (sd**2 / n + tau**2).numpy()
    r = (m - mu).numpy()
    dens = (1 - share) * norm.pdf(r, scale=np.sqrt(vm)) + share * norm.pdf(
        r, scale=np.sqrt(vm + extra.numpy() ** 2)
    )
    var = (sd**2).numpy()
    spread = 0.5 * ((n.numpy() - 1) * (np.log(var) + math.log(2 * math.pi)) + m2.numpy() / var)
    want = float(np.sum(-np.log(dens) + spread + 0.5 * np.log(n.numpy())))
    assert got == np.float64(want) or abs(got - want) < 1e-9 * abs(want)
    # and the Gaussian's NLL differs from it (the mixture enters)
    assert abs(float(_gauss_ss(n, m, m2, mu, sd, tau, None)) - got) > 1.0


def test_sparse_gain_sits_on_the_share():
    """``PixelGain(rms, share=s)``: a share s of the pixels (within 3 binomial sd) moves, the
    others read gain 1; ``share=1`` is the dense gain map of the same seed."""
    like = torch.zeros(1, dtype=torch.float64)
    h, w, s = 120, 150, 0.07
    g = PixelGain(0.05, seed=11, share=s).gain(h, w, like)[0, 0]
    moved = float((g != 1.0).double().mean())
    assert abs(moved - s) < 3 * math.sqrt(s * (1 - s) / (h * w))
    dense = PixelGain(0.05, seed=11).gain(h, w, like)[0, 0]
    on = g != 1.0
    assert torch.equal(g[on], dense[on])  # the same draws where the gain sits
    try:
        PixelGain(0.05, share=0.0)
    except ValueError as e:
        assert "share" in str(e)
    else:
        raise AssertionError("share 0 accepted")


def test_weak_rows_and_clusters_are_named_pixel_gain():
    """Two weak rows and six 3 x 3 clusters at gain 0.9 (7 % of the pixels; two levels, not
    the member's Gaussian): named ``pixel_gain`` alone, through the sparse member, whose share
    is within a factor of two of the planted one."""
    from test_diagnosis import H, W, _recording

    from tof_fpn_torch.diagnosis import diagnose

    g = torch.ones(H, W, dtype=torch.float64)
    g[[9, 27]] = 0.9
    for cy, cx in [(4, 6), (15, 40), (20, 12), (33, 30), (36, 50), (24, 47)]:
        g[cy - 1 : cy + 2, cx - 1 : cx + 2] = 0.9
    planted = float((g < 1).double().mean())
    rec, sd = _recording(PixelGain(gain_map=g), seed=6)
    diag = diagnose(rec, sd, replicates=0)
    assert diag.report["verdict"] == ["pixel_gain"], diag.report["effects"]
    eff = diag.report["effects"][0]
    assert "pixel_gain_sparse" in eff["terms"], eff
    share = eff["params"]["share_of_pixels_percent"] / 100
    assert planted / 2 < share < planted * 2, (share, planted)
