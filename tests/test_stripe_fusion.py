"""The eq. (11) fusion fitted to the measured stripes (analysis.stripe_fusion, build.fusion_from_data)
and the gate's calibrated stripe scale."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.analysis.stripe_fusion import (
    AmplitudeBins,
    _bin_stripe_power,
    fit_fusion,
    stripe_power_by_amplitude,
)
from tof_fpn_torch.build import (
    filter_from_design,
    fusion_from_data,
    suppression_from_data,
    suppression_from_design,
)
from tof_fpn_torch.runtime import FPNSuppression


def _terraces(h: int, w: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A scene model of its own (not the simulator's): terraces of slanted planes at random
    heights, separated by horizontal and vertical steps, and an amplitude that falls with depth
    and has a per-terrace reflectance."""
    g = torch.Generator().manual_seed(seed)
    yy = torch.arange(h, dtype=torch.float64).view(-1, 1)
    xx = torch.arange(w, dtype=torch.float64).view(1, -1)
    depth = 2.5 + 0.002 * xx + 0.001 * yy
    refl = torch.full((h, w), 0.7, dtype=torch.float64)
    for _ in range(6):
        y0, x0 = (
            int(torch.randint(0, h - 10, (1,), generator=g)),
            int(torch.randint(0, w - 10, (1,), generator=g)),
        )
        m = (yy >= y0) & (xx >= x0)
        depth = torch.where(m, depth + 0.4 * (float(torch.rand(1, generator=g)) - 0.5), depth)
        refl = torch.where(m, 0.3 + 0.7 * torch.rand(1, generator=g, dtype=torch.float64), refl)
    amp = 120.0 * refl / (depth / 2.5) ** 2
    return depth.view(1, 1, h, w), amp.view(1, 1, h, w)


def _striped(h, w, law, seed, stripe=0.03, k=0.3):
    """(truth, amplitude, striped noisy frame, the stripes alone) in float64."""
    gt, amp = _terraces(h, w, seed)
    g = torch.Generator().manual_seed(seed + 1)
    noisy = gt + k / amp * torch.randn(gt.shape, generator=g, dtype=torch.float64)
    n = torch.arange(w, dtype=torch.float64)
    p = torch.cos(math.pi * n) + 0.8 * torch.cos(2 * math.pi / 3 * n + 1.1)
    med = float(amp.median())
    law_a = {"inverse": med / amp, "exponential": torch.exp(-(amp - med) / 30.0)}.get(
        law, torch.ones_like(amp)
    )
    stripes = stripe * law_a * p
    return gt, amp, noisy + stripes, stripes


def test_stripe_power_per_bin_follows_the_law_it_was_not_told():
    """The stripe power measured per amplitude bin against the power of the stripes the notch
    actually removes (the stripes alone through the filter), for a law falling as 1 / A: within
    35 % in every bin, and the bins' trend falls as the truth does."""
    gt, amp, x, stripes = _striped(240, 320, "inverse", seed=11)
    filt = filter_from_design()
    bins = stripe_power_by_amplitude(x, amp, filt)
    removed = filt(stripes + 10.0) - (stripes + 10.0)  # what the notch takes of the stripes
    idx = torch.bucketize(amp.flatten(), bins.edges[1:-1], right=True)
    truth = torch.stack(
        [(removed.flatten()[idx == b] ** 2).mean() for b in range(len(bins.pixels))]
    )
    ratio = bins.stripe_power / truth
    assert bool(((ratio > 0.65) & (ratio < 1.35)).all()), ratio
    assert float(bins.stripe_power[0]) > 2.0 * float(bins.stripe_power[-1])


def test_no_stripes_measures_no_stripe_power():
    """The same scene without stripes: the measured stripe power is below 2 % of the noise power
    in every bin (it is 0 in expectation); with them it is above 10x the noise power."""
    gt, amp, x, stripes = _striped(240, 320, "constant", seed=12)
    free = stripe_power_by_amplitude(x - stripes, amp, filter_from_design())
    assert float((free.stripe_power / free.noise_power).max()) < 0.02, free
    striped = stripe_power_by_amplitude(x, amp, filter_from_design())
    assert float((striped.stripe_power / striped.noise_power).min()) > 10.0, striped


def test_bin_stripe_power_against_numpy():
    """The per-bin estimator (halves' means product over the cross-power, or the bias-corrected
    square) against a NumPy transcription of the formula."""
    rng = np.random.default_rng(3)
    n = 500
    other = rng.normal(size=(n, 2))
    own = other + 0.3 * rng.normal(size=(n, 2))
    d = -0.7 * other[:, 0] + 0.2 * other[:, 1] + 0.5 * rng.normal(size=n)
    for side in (np.r_[np.zeros(250), np.ones(250)], np.r_[np.zeros(480), np.ones(20)]):
        ref = 0.0
        for i in range(2):
            t = d * other[:, i]
            cross = np.mean(other[:, i] * own[:, i])
            a, b = t[side == 0], t[side == 1]
            if min(a.size, b.size) >= 50:
                ref += max(a.mean() * b.mean(), 0.0) / cross
            else:
                ref += max(t.mean() ** 2 - t.var(ddof=1) / n, 0.0) / cross
        got = _bin_stripe_power(
            torch.from_numpy(d),
            torch.from_numpy(other),
            torch.from_numpy(own),
            torch.from_numpy(np.stack([side, side], 1)),
        )
        assert got == pytest.approx(ref, rel=1e-12)


@pytest.mark.slow
def test_fit_fusion_matches_a_brute_force_search():
    """The closed-form floor per threshold pair against a dense NumPy search over the floor."""
    rng = np.random.default_rng(0)
    for trial in range(4):
        nb = 9
        amp = np.sort(rng.uniform(20, 200, nb))
        edges = np.r_[amp[0] - 5, (amp[1:] + amp[:-1]) / 2, amp[-1] + 5]
        change = rng.uniform(0.5, 2.0, nb)
        stripe = np.clip(rng.uniform(-0.2, 1.0, nb) * change, 0, None)
        noise = rng.uniform(0.0, 0.2, nb)
        pixels = rng.integers(100, 1000, nb).astype(float)
        t = lambda v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
        bins = AmplitudeBins(t(edges), t(amp), t(pixels), t(stripe), t(noise), t(change), 0.7)
        low, high, floor = fit_fusion(bins)
        target = np.clip((stripe + 0.3 * noise) / change, 0, 1)
        cost = pixels * change

        def err(lo, hi, fl, amp=amp, cost=cost, target=target):
            w = np.clip(1 - (1 - fl) * (amp - lo) / (hi - lo), fl, 1)
            return float(np.sum(cost * (w - target) ** 2))

        cand = sorted({0.0, *edges.tolist(), 2 * edges[-1] + 1})
        best = min(
            err(lo, hi, fl)
            for lo, hi in itertools.combinations(cand, 2)
            for fl in np.linspace(0, 1, 2001)
        )
        assert err(low, high, floor) <= best + 1e-9, trial


@pytest.mark.parametrize("law", ["inverse", "exponential", "constant"])
def test_data_stage_gains_what_the_best_thresholds_gain(law):
    """On a scene model of its own with stripes following each law: ``suppression_from_data``
    gains >= 80 % of the best design stage over a grid of thresholds and floors chosen by the
    PSNR against the truth (the noise-law thresholds, fusion_from_noise, gain about 10 % of it)."""
    gt, amp, x, _ = _striped(204, 204, law, seed=21, stripe=0.06, k=0.5)
    p0 = float(psnr(x, gt))
    gain = float(psnr(suppression_from_data(x, amp)(x, amp), gt)) - p0
    q = [float(v) for v in torch.quantile(amp.flatten(), torch.tensor([0.1, 0.5, 0.9]).double())]
    best = max(
        float(psnr(suppression_from_design(low=lo, high=lo + s, floor=f)(x, amp), gt)) - p0
        for lo, s, f in itertools.product([0.0, *q], (10.0, 60.0, 200.0), (0.0, 0.2, 0.5))
    )
    assert best > 1.0
    assert gain >= 0.8 * best, (gain, best)


def test_fusion_from_data_refuses_tiny_frames_and_keeps_its_bins():
    gt, amp, x, _ = _striped(64, 96, "inverse", seed=5)
    fusion = fusion_from_data(x, amp)
    assert fusion.bins is not None and len(fusion.bins.pixels) >= 2
    with pytest.raises(ValueError, match="too few valid pixels"):
        fusion_from_data(x[..., :20, :20], amp[..., :20, :20])


def test_stripe_scale_is_checked_and_scripts():
    stage = suppression_from_design()
    with pytest.raises(ValueError, match="stripe_scale"):
        FPNSuppression(stage.filter, stage.fusion, stripe_scale=0.0)
    gt, amp, x, _ = _striped(96, 128, "exponential", seed=8, stripe=0.04)
    x, amp = x.float(), amp.float()
    built = suppression_from_data(x, amp)
    assert built.stripe_scale != 1.0
    scripted = torch.jit.script(built)
    assert torch.equal(scripted(x, amp), built(x, amp))
    more = FPNSuppression(built.filter, built.fusion, stripe_scale=8.0)
    less = FPNSuppression(built.filter, built.fusion, stripe_scale=0.25)
    # a larger stripe power opens the risk check further: the output moves at least as far
    assert float((more(x, amp) - x).abs().sum()) >= float((less(x, amp) - x).abs().sum())
