"""Scene generators: Fig.-7-like synthetic scene and the Sec. IV-A planar layout."""

from __future__ import annotations

import pytest
import torch

from tof_fpn_torch.sim import MATERIALS, Scene, planar_scene, synthetic_scene, unambiguous_range


def test_synthetic_scene_is_deterministic_from_seed():
    a = synthetic_scene(seed=5)
    b = synthetic_scene(seed=5)
    c = synthetic_scene(seed=6)
    assert torch.equal(a.depth, b.depth) and torch.equal(a.amplitude, b.amplitude)
    assert not torch.equal(a.depth, c.depth)
    d64 = synthetic_scene(seed=5, dtype=torch.float64)
    torch.testing.assert_close(d64.depth.float(), a.depth)
    batch = synthetic_scene(seed=5, batch=2)
    assert torch.equal(batch.depth[1:], c.depth)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_synthetic_scene_ranges_and_detail(seed):
    s = synthetic_scene(seed=seed)
    assert s.depth.shape == (1, 1, 204, 204)
    assert float(s.depth.min()) > 0 and float(s.depth.max()) <= 7.5
    assert float(s.depth.max()) < unambiguous_range(20e6)
    assert float(s.depth.max() - s.depth.min()) > 4.0  # uses most of [0, 7.5] m
    a = s.amplitude
    assert float(a.min()) >= 0 and float(a.max()) <= 300
    assert float(a.min()) < 30 and float(a.max()) > 200  # spans the low-sensing range
    # edges and fine details: many depth steps > 0.3 m between neighbours, also 1-px structures
    d = s.depth[0, 0]
    steps = ((d[:, 1:] - d[:, :-1]).abs() > 0.3).float().mean()
    assert float(steps) > 0.01
    thin = ((d[:, 1:-1] - d[:, :-2]).abs() > 0.3) & ((d[:, 1:-1] - d[:, 2:]).abs() > 0.3)
    assert int(thin.sum()) > 20  # one-pixel-wide features
    assert torch.equal(s.reflectance, torch.clamp(a / 300, 0.01, 1))


def test_planar_scene_layout():
    depths = (1.2, 1.8, 2.4, 3.0, 3.6)
    s = planar_scene(seed=0, depths=depths, wall_depth=4.5)
    levels = set(torch.unique(s.depth).tolist())
    allowed = {float(torch.tensor(v)) for v in (*depths, 4.5)}
    assert levels <= allowed and len(levels) >= 5  # fronto-parallel planes, mostly all visible
    # materials of different reflectance: several distinct values, including a dark and a bright
    r = s.reflectance
    assert float(r.min()) <= MATERIALS["black cloth"] + 0.02 and float(r.max()) >= 0.8
    assert torch.unique(torch.round(r * 100)).numel() >= 5
    assert torch.equal(planar_scene(seed=0).depth, s.depth)


def test_scene_validation_errors():
    d = torch.full((1, 1, 4, 4), 2.0)
    r = torch.full((1, 1, 4, 4), 0.5)
    with pytest.raises(ValueError, match="shape"):
        Scene(d[0], r[0])
    with pytest.raises(ValueError, match="shape of depth"):
        Scene(d, r[..., :2])
    with pytest.raises(ValueError, match="reflectance"):
        Scene(d, r * 3)
    with pytest.raises(ValueError, match="amplitude"):
        Scene(d, r, -r)
    with pytest.raises(ValueError, match="height"):
        synthetic_scene(8, 204)
    with pytest.raises(ValueError, match="depth_range"):
        synthetic_scene(depth_range=(0.0, 7.5))
    with pytest.raises(ValueError, match="seed"):
        synthetic_scene(seed=-1)
    with pytest.raises(ValueError, match="wall_depth"):
        planar_scene(depths=(1.0, 5.0), wall_depth=4.5)
