"""Tests of HypothesisBilateral and LPAICI: brute-force NumPy references of their definitions,
edge preservation, TorchScript, holes, bad input. CPU, seeded, small images."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.denoise import LPAICI, HypothesisBilateral, hypothesis_bilateral, lpa_ici
from tof_fpn_torch.denoise.lpa_ici import lpa_kernels
from tof_fpn_torch.sim import synthetic_scene


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def _step(h=24, w=28, sigma=0.05, seed=0):
    g = torch.Generator().manual_seed(seed)
    clean = torch.ones(1, 1, h, w, dtype=torch.float64)
    clean[..., w // 2 :] = 2.0
    return clean, clean + sigma * torch.randn(clean.shape, generator=g, dtype=torch.float64)


def hypbi_reference(d, guide, sig, L, ks, ss, sc, trunc):
    """Per pixel: hypotheses d(p) + linspace(-1, 1, L) * trunc * sig(p), cost = the window's
    spatial x range weighted mean of min((h - d(q))^2, (trunc sig(p))^2), argmin, parabola."""
    H, W = d.shape
    r = ks // 2
    out = d.copy()
    for y in range(H):
        for x in range(W):
            tau = trunc * sig[y, x]
            hyp = d[y, x] + np.linspace(-1, 1, L) * tau
            cost = np.zeros(L)
            norm = 0.0
            for dy in range(-r, r + 1):
                for dx in range(-r, r + 1):
                    yy, xx = y + dy, x + dx
                    if not (0 <= yy < H and 0 <= xx < W):
                        continue
                    w = math.exp(-(dy * dy + dx * dx) / (2 * ss * ss))
                    w *= math.exp(-((guide[yy, xx] - guide[y, x]) ** 2) / (2 * sc * sc))
                    cost += w * np.minimum((hyp - d[yy, xx]) ** 2, tau * tau)
                    norm += w
            cost /= norm
            i = int(np.argmin(cost))
            o = 0.0
            if 0 < i < L - 1:
                den = cost[i - 1] + cost[i + 1] - 2 * cost[i]
                if den > 0:
                    o = float(np.clip((cost[i - 1] - cost[i + 1]) / (2 * den), -0.5, 0.5))
            out[y, x] = d[y, x] - tau + (i + o) * 2 * tau / (L - 1)
    return out


def test_hypbi_equals_bruteforce_reference():
    scene = synthetic_scene(16, 16, seed=1)
    g = torch.Generator().manual_seed(1)
    d = scene.depth.double()[..., :14, :] + 0.03 * torch.randn(
        1, 1, 14, 16, generator=g, dtype=torch.float64
    )
    amp = scene.amplitude.double()[..., :14, :] + 1.0
    ours = hypothesis_bilateral(d, amp, sigma=0.03, hypotheses=9, sigma_color=20.0)
    ref = hypbi_reference(
        d[0, 0].numpy(), amp[0, 0].numpy(), np.full((14, 16), 0.03), 9, 7, 2.0, 20.0, 3.0
    )
    np.testing.assert_allclose(ours[0, 0].numpy(), ref, atol=1e-10)


def test_hypbi_keeps_edges_and_scripts():
    clean, noisy = _step()
    m = HypothesisBilateral()
    out = m(noisy.float(), sigma=0.05)
    err = (out.double() - clean).abs()
    assert float(err.mean()) < 0.3 * float((noisy - clean).abs().mean())
    assert float(err[..., 12:16].max()) < 0.25  # the 1 m step is not smeared
    amp = 50.0 + 10.0 * (clean > 1.5).float()
    s = torch.jit.script(m)
    for kw in ({}, {"sigma": 0.05}, {"amplitude": amp}):
        torch.testing.assert_close(s(noisy.float(), **kw), m(noisy.float(), **kw), atol=0, rtol=0)


def test_lpa_kernels():
    k = lpa_kernels(8, [1, 2, 3, 5], 0)
    assert k.shape == (32, 1, 9, 9)
    torch.testing.assert_close(k.sum((1, 2, 3)), torch.ones(32, dtype=torch.float64))
    assert float(k[0, 0, 4, 4]) == 1.0  # h = 1: the pixel itself
    k1 = lpa_kernels(8, [3, 5], 1)  # order 1: a line along the direction is reproduced
    u = torch.arange(-4, 5, dtype=torch.float64)
    yy, xx = torch.meshgrid(u, u, indexing="ij")
    for d in range(8):
        th = 2 * math.pi * d / 8
        along = xx * math.cos(th) + yy * math.sin(th)
        for s in range(2):
            g = k1[2 * d + s, 0]
            assert abs(float(g.sum()) - 1.0) < 1e-9
            assert abs(float((g * (0.7 * along + 2.0)).sum()) - 2.0) < 1e-9


def lpa_reference(z, var, kernels, D, gamma):
    """ICI per direction and pixel, inverse-variance fusion (NumPy, zero-padded, normalised)."""
    H, W = z.shape
    R = kernels.shape[-1] // 2
    S = kernels.shape[0] // D
    zp = np.pad(z, R)
    vp = np.pad(var, R)
    mp = np.pad(np.ones_like(z), R)
    out = np.zeros_like(z)
    for y in range(H):
        for x in range(W):
            num = den = 0.0
            for d in range(D):
                lo, hi = -np.inf, np.inf
                best = None
                for s in range(S):
                    g = kernels[d * S + s, 0]
                    win = (slice(y, y + 2 * R + 1), slice(x, x + 2 * R + 1))
                    n = (g * mp[win]).sum()
                    est = (g * zp[win]).sum() / n
                    sd = math.sqrt((g * g * vp[win]).sum()) / n
                    lo, hi = max(lo, est - gamma * sd), min(hi, est + gamma * sd)
                    if lo > hi:
                        break
                    best = (est, sd)
                num += best[0] / best[1] ** 2
                den += 1.0 / best[1] ** 2
            out[y, x] = num / den
    return out


def test_lpa_ici_equals_bruteforce_reference():
    clean, noisy = _step(12, 14, sigma=0.1)
    sig = torch.full_like(noisy, 0.1)
    sig[..., :6, :] = 0.2  # a noise map
    ours = lpa_ici(noisy, sigma=sig, scales=(1, 2, 3, 4))
    k = lpa_kernels(8, [1, 2, 3, 4], 0).numpy()
    ref = lpa_reference(noisy[0, 0].numpy(), sig[0, 0].numpy() ** 2, k, 8, 1.5)
    np.testing.assert_allclose(ours[0, 0].numpy(), ref, atol=1e-10)


def test_lpa_ici_quality_script_holes_and_errors():
    clean, noisy = _step(32, 40, sigma=0.05)
    m = LPAICI()
    out = m(noisy.float(), sigma=0.05).double()
    assert float((out - clean)[..., :, :16].std()) < 0.35 * 0.05  # flat part smoothed
    assert float((out - clean)[..., 18:22].abs().max()) < 0.25  # edge kept
    s = torch.jit.script(m)
    x = noisy.float()
    for kw in ({}, {"sigma": 0.05}, {"amplitude": torch.full_like(x, 20.0)}):
        torch.testing.assert_close(s(x, **kw), m(x, **kw), atol=0, rtol=0)
    holes = torch.zeros_like(x, dtype=torch.bool)
    holes[..., 10:14, 5:9] = True
    xh = torch.where(holes, torch.full_like(x, math.nan), x)
    for mod in (LPAICI(), LPAICI(order=1), HypothesisBilateral()):
        oh = mod(xh, sigma=0.05)
        assert bool(oh[holes].isnan().all()) and bool(torch.isfinite(oh[~holes]).all())
        torch.testing.assert_close(mod(x, sigma=0.0), x, atol=0, rtol=0)
        allbad = torch.zeros(1, 1, 12, 12)
        torch.testing.assert_close(mod(allbad, sigma=0.1), allbad)
    for kw, msg in (
        ({"scales": (2, 1)}, "increasing"),
        ({"order": 2}, "order"),
        ({"gamma": 0.0}, "gamma"),
        ({"directions": 0}, "directions"),
    ):
        with pytest.raises(ValueError, match=msg):
            LPAICI(**kw)
    for kw, msg in (
        ({"hypotheses": 2}, "hypotheses"),
        ({"kernel_size": 4}, "kernel_size"),
        ({"trunc": 0.0}, "trunc"),
        ({"iterations": 0}, "iterations"),
        ({"hypotheses": 5.0}, "must be an int"),
    ):
        with pytest.raises(ValueError, match=msg):
            HypothesisBilateral(**kw)
    with pytest.raises(ValueError, match="sigma must be a finite number >= 0"):
        LPAICI()(x, sigma=-1.0)
