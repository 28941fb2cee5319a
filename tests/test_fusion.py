"""AmplitudeFusion (eq. 11) against an independent NumPy formulation (np.interp)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tof_fpn_torch import AmplitudeFusion


def _numpy_fusion(filtered, depth, amplitude, low, high, floor):
    delta = np.interp(amplitude, [low, high], [1.0, floor])  # flat outside [low, high]
    return delta * filtered + (1.0 - delta) * depth


@pytest.mark.parametrize("params", [(70.0, 350.0, 0.2), (10.0, 50.0, 0.0), (0.0, 1.0, 1.0)])
def test_matches_numpy_interp(params):
    g = torch.Generator().manual_seed(1)
    depth = torch.rand(2, 1, 9, 11, generator=g, dtype=torch.float64) + 1.0
    filtered = depth + 0.1 * torch.randn(2, 1, 9, 11, generator=g, dtype=torch.float64)
    amplitude = torch.rand(2, 1, 9, 11, generator=g, dtype=torch.float64) * 1.5 * params[1]
    fuse = AmplitudeFusion(*params)
    out = fuse(filtered, depth, amplitude)
    ref = _numpy_fusion(filtered.numpy(), depth.numpy(), amplitude.numpy(), *params)
    np.testing.assert_allclose(out.numpy(), ref, rtol=0, atol=1e-12)


def test_weight_knots_paper_values():
    fuse = AmplitudeFusion()
    a = torch.tensor([0.0, 70.0, 210.0, 350.0, 5000.0])
    torch.testing.assert_close(fuse.weight(a), torch.tensor([1.0, 1.0, 0.6, 0.2, 0.2]))


def test_invalid_depth_stays_invalid():
    fuse = AmplitudeFusion()
    depth = torch.tensor([[[[float("nan"), 0.0, 2.0]]]])
    filtered = torch.tensor([[[[float("nan"), 0.0, 2.5]]]])
    out = fuse(filtered, depth, torch.tensor([[[[10.0, 400.0, 210.0]]]]))
    assert torch.isnan(out[0, 0, 0, 0]) and out[0, 0, 0, 1] == 0
    torch.testing.assert_close(out[0, 0, 0, 2], torch.tensor(2.3))


def test_torchscript_and_gradcheck():
    fuse = AmplitudeFusion()
    s = torch.jit.script(fuse)
    g = torch.Generator().manual_seed(2)
    d = torch.rand(1, 1, 3, 4, generator=g, dtype=torch.float64) + 1
    f = d + 0.1
    a = torch.rand(1, 1, 3, 4, generator=g, dtype=torch.float64) * 400
    torch.testing.assert_close(s(f, d, a), fuse(f, d, a), rtol=0, atol=0)
    d.requires_grad_(True)
    f.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x, y: fuse(x, y, a), (f, d))


def test_errors():
    with pytest.raises(ValueError, match="low < high"):
        AmplitudeFusion(350.0, 70.0)
    with pytest.raises(ValueError, match=r"floor must lie in \[0, 1\], got 1.5"):
        AmplitudeFusion(floor=1.5)
    with pytest.raises(ValueError, match="finite"):
        AmplitudeFusion(low=float("nan"))
    fuse = AmplitudeFusion()
    d = torch.ones(1, 1, 2, 2)
    # a negative or NaN amplitude is no measurement: that pixel keeps its raw depth
    out = fuse(d + 1, d, torch.tensor([[[[1.0, -3.0], [float("nan"), 1.0]]]]))
    assert out.tolist() == [[[[2.0, 1.0], [1.0, 2.0]]]]
    with pytest.raises(ValueError, match=r"same shape, got \[1, 1, 2, 3\] and \[1, 1, 2, 2\]"):
        fuse(d, d, torch.ones(1, 1, 2, 3))
    with pytest.raises(ValueError, match="1 channel"):
        fuse(torch.ones(1, 2, 2, 2), torch.ones(1, 2, 2, 2), torch.ones(1, 2, 2, 2))
