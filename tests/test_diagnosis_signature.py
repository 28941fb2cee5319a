"""Signature shares (:mod:`tof_fpn_torch.diagnosis.signature`): the share of a misfit that is
fine in space (a per-pixel gain or offset) or sporadic in time (impulsive frame-pixels), which
scales a spread term's held-out gain in the ranking."""

from __future__ import annotations

import math
from types import SimpleNamespace

import torch

from tof_fpn_torch.diagnosis.signature import (
    FINE_SCALE_PX,
    common_share,
    defect_pixels,
    dense_share,
    fine_share,
    sporadic_share,
)
from tof_fpn_torch.sim import Camera

H, W, T = 60, 80, 20


def _case(res_a, res_d=None, depth=None, frames=None):
    """obs / ctx / pred with amplitude 100, noise of the means 0.01 (amplitude) and 1e-4 m."""
    mu = torch.full((H, W), 100.0, dtype=torch.float64)
    n = torch.full((H, W), float(T), dtype=torch.float64)
    depth = torch.full((H, W), 2.0, dtype=torch.float64) if depth is None else depth
    m_d = depth + (0 if res_d is None else res_d)
    obs = SimpleNamespace(
        m_a=mu + res_a,
        m_d=m_d,
        n=n,
        scene_depth=depth,
        depth=frames,
        amplitude=None if frames is None else mu.expand(T, H, W).clone(),
        valid=None if frames is None else torch.ones(T, H, W, dtype=torch.bool),
        frames=T,
        camera=Camera,
    )
    ones = torch.ones(H, W, dtype=torch.bool)
    ctx = SimpleNamespace(mask_a=ones, mask_d=ones)
    sd_a = torch.full((H, W), 0.01 * math.sqrt(T), dtype=torch.float64)
    sd_d = torch.full((H, W), 1e-4 * math.sqrt(T), dtype=torch.float64)
    pred = SimpleNamespace(mu_a=mu, sd_a=sd_a, mu_d=depth, sd_d=sd_d, a0=mu, wrap=None)
    return obs, ctx, pred


def _smooth_field(scale: float) -> torch.Tensor:
    yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    return torch.exp(-((yy - 20.0) ** 2 + (xx - 50.0) ** 2) / (2 * scale**2)).double()


def test_fine_share_tells_a_pixel_gain_from_a_smooth_misfit():
    """A white gain per pixel: nearly all of its excess variance is fine; a bump of light 2.5 x
    the smoothing scale wide: little of it; both stay so with a depth edge through the frame
    (the smoothing does not cross it, and a step of the misfit at the edge is not fine)."""
    gen = torch.Generator().manual_seed(0)
    gain = 0.02 * torch.randn(H, W, generator=gen, dtype=torch.float64)
    bump = 5.0 * _smooth_field(2.5 * FINE_SCALE_PX)
    edge = torch.where(torch.arange(W).view(1, W) < W // 2, 2.0, 3.0).expand(H, W).double()
    assert fine_share(*_case(100.0 * gain)) > 0.9
    assert fine_share(*_case(bump)) < 0.1
    stepped = torch.where(edge > 2.5, 2.0 * bump, bump)
    assert fine_share(*_case(stepped, depth=edge)) < 0.1
    # a mixture: the gain's share of the excess variance
    want = float((100.0 * gain).pow(2).mean()) / float((stepped + 100.0 * gain).pow(2).mean())
    assert abs(fine_share(*_case(stepped + 100.0 * gain, depth=edge)) - want) < 0.05
    assert fine_share(*_case(torch.zeros(H, W, dtype=torch.float64))) is None  # nothing to share


def test_fine_share_of_the_phasor_sees_depth_columns():
    """Column delays (a read-out pattern) are fine in the phasor's residual; a smooth depth
    bias is not."""
    gen = torch.Generator().manual_seed(1)
    cols = 0.003 * torch.randn(1, W, generator=gen, dtype=torch.float64).expand(H, W)
    zero = torch.zeros(H, W, dtype=torch.float64)
    assert fine_share(*_case(zero, res_d=cols), phasor=True) > 0.9
    assert fine_share(*_case(zero, res_d=0.01 * _smooth_field(30.0)), phasor=True) < 0.1


def test_sporadic_share_tells_impulses_from_a_fixed_misfit():
    """Outliers in a quarter of the frames of their pixels: all sporadic; a block of pixels off
    in every frame: none; lone pixels far off in every frame (hot pixels, a defect of each
    pixel alone): all; no outlier: None."""
    depth = torch.full((H, W), 2.0, dtype=torch.float64)
    frames = depth.expand(T, H, W).clone()
    gen = torch.Generator().manual_seed(2)
    hot = torch.rand(H, W, generator=gen) < 0.01
    fire = torch.rand(T, H, W, generator=gen) < 0.25
    sporadic = torch.where(hot & fire, frames + 1.0, frames)
    block = torch.zeros(H, W, dtype=torch.bool)
    block[10:20, 10:30] = True
    fixed = torch.where(block.expand(T, H, W), frames + 1.0, frames)
    lone = torch.zeros(H, W, dtype=torch.bool)
    lone[3::7, 3::7] = True
    defects = torch.where(lone.expand(T, H, W), frames + 1.0, frames)

    def share(x):
        return sporadic_share(*_case(0.0 * depth, res_d=x.mean(0) - depth, depth=depth, frames=x))

    assert share(sporadic) == 1.0
    assert share(fixed) == 0.0
    assert share(defects) == 1.0
    assert share(frames) is None


def test_dense_share_leaves_lone_defects_out():
    """The means' excess spread of a dense random offset is all dense; of lone pixels far off
    (with a weak dense offset beside them) almost none; the defect pixels are the lone ones."""
    depth = torch.full((H, W), 2.0, dtype=torch.float64)
    gen = torch.Generator().manual_seed(4)
    dense = 3e-4 * torch.randn(H, W, generator=gen, dtype=torch.float64)
    obs, ctx, pred = _case(0.0 * depth, res_d=dense, depth=depth)
    assert dense_share(obs, ctx, pred) > 0.99
    assert int(defect_pixels(obs, ctx, pred).sum()) == 0
    lone = torch.zeros(H, W, dtype=torch.bool)
    lone[3::7, 3::7] = True
    obs, ctx, pred = _case(0.0 * depth, res_d=dense + 0.05 * lone, depth=depth)
    assert dense_share(obs, ctx, pred) < 0.05
    assert torch.equal(defect_pixels(obs, ctx, pred), lone)


def test_common_share_tells_a_drift_from_outliers():
    """A delay that moves every pixel of a frame: its frames' median course is their mean
    course (share 1); hot pixels in some frames move the frames' means, not their medians."""
    depth = torch.full((H, W), 2.0, dtype=torch.float64)
    frames = depth.expand(T, H, W).clone()
    gen = torch.Generator().manual_seed(3)
    frames = frames + 1e-4 * torch.randn(T, H, W, generator=gen, dtype=torch.float64)
    walk = 0.002 * torch.randn(T, generator=gen, dtype=torch.float64).cumsum(0)
    drift = frames + walk.view(T, 1, 1)
    hot = (torch.rand(T, H, W, generator=gen) < 0.002) & (torch.arange(T) % 3 == 0).view(T, 1, 1)
    spikes = torch.where(hot, frames + 2.0, frames)
    assert common_share(*_case(0.0 * depth, depth=depth, frames=drift)) > 0.95
    assert common_share(*_case(0.0 * depth, depth=depth, frames=spikes)) < 0.05


def test_fine_share_does_not_take_the_scenes_texture_for_fine_structure():
    """A smooth gain on a scene with a textured amplitude is a smooth misfit, whether it is
    read in DN (gain times a textured amplitude) or relative to the amplitude; so is a smooth
    offset (relative to a textured amplitude it would look fine). The gain and offset per pixel
    stay fine in both frames. Read in one frame only, the smooth ones are not."""
    gen = torch.Generator().manual_seed(5)
    tex = 100.0 * torch.exp(0.5 * torch.randn(H, W, generator=gen, dtype=torch.float64))

    def case(res_a, res_d=None):
        obs, ctx, pred = _case(res_a, res_d)
        obs.m_a = tex + res_a
        pred.mu_a = pred.a0 = tex
        return obs, ctx, pred

    smooth = 0.05 * _smooth_field(2.5 * FINE_SCALE_PX)
    white = 0.02 * torch.randn(H, W, generator=gen, dtype=torch.float64)
    for phasor in (False, True):
        assert fine_share(*case(smooth * tex), phasor=phasor) < 0.1  # a smooth gain
        assert fine_share(*case(5.0 * smooth / 0.05), phasor=phasor) < 0.1  # a smooth offset
        assert fine_share(*case(white * tex), phasor=phasor) > 0.9  # a gain per pixel
        assert fine_share(*case(100.0 * white), phasor=phasor) > 0.9  # an offset per pixel
    # in DN alone, a good part of the smooth gain looks fine: the scene's texture
    obs, ctx, pred = case(smooth * tex)
    from tof_fpn_torch.diagnosis.signature import _fine

    va = pred.sd_a**2 / obs.n
    m = torch.ones(H, W, dtype=torch.bool)
    assert _fine([obs.m_a - tex], [va], m, obs.scene_depth) > 0.2


def test_common_share_of_a_weak_drift_under_heavy_tailed_noise():
    """Under Student-t noise (2.5 degrees of freedom) the frames' mean course carries more
    sampling noise than their median course. Noise alone has no established course: None (a
    ratio of the courses' variances, the share before, gave 0.21-0.45 here, and scaled a real
    drift's gain by it where the likelihood resolves a drift these plain means do not). A
    warm-up of 0.5 per-pixel sd over the recording: established, and common to the pixels."""
    depth = torch.full((H, W), 2.0, dtype=torch.float64)
    sd = 1e-4 * math.sqrt(T)
    for seed in range(10, 16):
        torch.manual_seed(seed)
        noise = torch.distributions.StudentT(2.5).sample((T, H, W)).double() * sd
        warm = torch.linspace(0, 0.5 * sd, T, dtype=torch.float64).view(T, 1, 1)
        assert common_share(*_case(0.0 * depth, depth=depth, frames=depth + noise + warm)) > 0.9
        assert common_share(*_case(0.0 * depth, depth=depth, frames=depth + noise)) is None
