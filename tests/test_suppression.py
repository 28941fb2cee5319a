"""FPNSuppression: filter + fusion against SciPy/NumPy, from_data, script, autograd, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.ndimage as ndi
import torch

from tof_fpn_torch import design_fpn
from tof_fpn_torch.build import suppression_from_data, suppression_from_design


def _inputs(b=2, h=40, w=96, seed=0):
    g = torch.Generator().manual_seed(seed)
    xx = torch.linspace(0, 1, w, dtype=torch.float64).expand(h, w)
    depth = (
        2.0
        + 0.5 * torch.sin(3 * xx)
        + 0.01 * torch.randn(b, 1, h, w, generator=g, dtype=torch.float64)
    )
    amplitude = torch.rand(b, 1, h, w, generator=g, dtype=torch.float64) * 500.0
    return depth, amplitude


def test_matches_scipy_plus_numpy_fusion():
    depth, amplitude = _inputs()
    m = suppression_from_design(gate=False)
    out = m(depth, amplitude)
    taps = design_fpn(20, 0.14).taps
    filtered = ndi.convolve1d(depth.numpy(), taps, axis=-1, mode="mirror")
    delta = np.interp(amplitude.numpy(), [70.0, 350.0], [1.0, 0.2])
    ref = delta * filtered + (1 - delta) * depth.numpy()
    np.testing.assert_allclose(out.numpy(), ref, rtol=0, atol=1e-12)
    plain = suppression_from_design(adaptive=False, gate=False)(depth)
    np.testing.assert_allclose(plain.numpy(), filtered, rtol=0, atol=1e-12)


def test_invalid_pixels_stay_invalid():
    depth, amplitude = _inputs()
    depth = depth.float()
    depth[0, 0, 3, 5] = float("nan")
    depth[1, 0, 10, 20:25] = 0.0
    out = suppression_from_design()(depth, amplitude.float())
    assert torch.isnan(out[0, 0, 3, 5]) and (out[1, 0, 10, 20:25] == 0).all()
    valid = torch.isfinite(depth) & (depth != 0)
    assert torch.isfinite(out[valid]).all() and (out[valid] != 0).all()


def test_torchscript_matches_eager():
    depth, amplitude = _inputs()
    depth = depth.float()
    depth[0, 0, 1, 2] = float("nan")
    for dim in (-1, (-2, -1)):
        m = suppression_from_design(order=41, rho=0.12, dim=dim)
        s = torch.jit.script(m)
        torch.testing.assert_close(
            s(depth, amplitude.float()), m(depth, amplitude.float()), rtol=0, atol=0, equal_nan=True
        )


def test_gradcheck_and_trainable():
    depth, amplitude = _inputs(1, 3, 16)
    m = suppression_from_design(trainable=True, gate=False)
    depth.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda d: m(d, amplitude), (depth,))
    assert isinstance(m.filter.taps, torch.nn.Parameter)
    m(depth, amplitude).sum().backward()
    assert m.filter.taps.grad is not None and m.filter.taps.grad.abs().sum() > 0


def _striped_frames(freqs, b=3, h=64, w=192, seed=0):
    g = torch.Generator().manual_seed(seed)
    xx = torch.arange(w, dtype=torch.float64).expand(h, w)
    d = (
        2.0
        + 0.4 * torch.sin(xx / 30.0)
        + 0.01 * torch.randn(b, 1, h, w, generator=g, dtype=torch.float64)
    )
    for f in freqs:
        d = d + 0.03 * torch.cos(f * xx + 0.2)
    return d, torch.full_like(d, 50.0)


def test_from_data_paper_frequencies():
    d, a = _striped_frames([2 * math.pi / 3, math.pi])
    m = suppression_from_data(d, a)
    notches = m.design.notches
    assert len(notches) == 2 and notches[1] == math.pi
    assert abs(notches[0] - 2 * math.pi / 3) < 0.01
    assert m.filter.dims == [-1] and m.estimate is not None


def test_from_data_other_frequency_is_suppressed():
    f0 = 0.45 * math.pi  # a worn sensor striping elsewhere
    d, a = _striped_frames([f0])
    m = suppression_from_data(d, a, order=30, adaptive=False)
    assert abs(m.design.notches[0] - f0) < 0.01
    clean, _ = _striped_frames([])
    with torch.inference_mode():
        out = m(d, a)
        m.gate = False  # the clean frame has no stripes: its gate would stay shut
        residual = (out - m(clean, a))[..., 40:-40]
    stripes = (d - clean)[..., 40:-40]
    ratio_db = 10 * math.log10(residual.pow(2).mean() / stripes.pow(2).mean())
    # the notch sits at the *estimated* frequency; the residual is set by the estimation error
    assert ratio_db < -25.0, ratio_db


def test_from_data_without_stripes_is_the_identity():
    """Nothing detected: no notch is built, and the stage returns its input unchanged."""
    d, a = _striped_frames([])
    m = suppression_from_data(d, a)
    assert m.filter is None and m.estimate.components == ()
    assert torch.equal(m(d, a), d)


def test_from_data_measures_the_fusion_thresholds_in_the_data_units():
    """The same frames with amplitudes in other units (x 20) get thresholds x 20: the gating
    follows the camera's units, not CamCube's."""
    g = torch.Generator().manual_seed(5)
    xx = torch.arange(192, dtype=torch.float64)
    a = 20.0 + 200.0 * torch.rand(3, 1, 64, 192, generator=g, dtype=torch.float64)
    d = 2.0 + 0.4 * torch.sin(xx / 30.0) + 0.03 * torch.cos(math.pi * xx)
    d = d + 0.5 / a * torch.randn(a.shape, generator=g, dtype=a.dtype)  # sigma_D = k / A
    m1 = suppression_from_data(d, a)
    m20 = suppression_from_data(d, 20.0 * a)
    assert m1.fusion.low == pytest.approx(m20.fusion.low / 20.0, rel=1e-6)
    assert m1.fusion.high == pytest.approx(m20.fusion.high / 20.0, rel=1e-6)
    assert m1.fusion.floor == pytest.approx(m20.fusion.floor, rel=1e-6)
    # 3 cm stripes at pi, the same at every amplitude, over 2.5-25 mm noise: the filtered depth
    # is worth more than the raw one everywhere, so the fitted weight stays near 1
    assert float(m1.fusion.weight(a).min()) > 0.9, m1.fusion


def test_errors_name_what_was_given():
    m = suppression_from_design()
    d = torch.ones(1, 1, 8, 8)
    with pytest.raises(ValueError, match="4 dimensions.*got 3"):
        m(torch.ones(1, 8, 8), d)
    with pytest.raises(ValueError, match=r"1 channel.*\[1, 2, 8, 8\]"):
        m(torch.ones(1, 2, 8, 8), torch.ones(1, 2, 8, 8))
    with pytest.raises(ValueError, match="floating-point.*torch.int32"):
        m(torch.ones(1, 1, 8, 8, dtype=torch.int32), d)
    with pytest.raises(ValueError, match=r"same shape, got \[1, 1, 8, 7\] and \[1, 1, 8, 8\]"):
        m(d, torch.ones(1, 1, 8, 7))
    out = m(d + 1.0, torch.where(d > 0, -d, d))  # negative amplitude: pixels left as they are
    torch.testing.assert_close(out, d + 1.0)
    with pytest.raises(ValueError, match="rho"):
        suppression_from_design(rho=0.5)


def test_real_adi_wall_frame(real_data):
    depth, amp = real_data.adi_wall()
    out = suppression_from_design()(depth, amp)
    invalid = depth == 0
    assert int(invalid.sum()) == 3  # the capture's three "no measurement" pixels
    assert (out[invalid] == 0).all()
    assert torch.isfinite(out).all()  # (a linear filter may ring below 0 next to the 3.6 m spikes)
    # where valid, the change is bounded by the stripe level (a few mm), not by smeared zeros
    change = (out - depth)[~invalid].abs()
    assert change.median() < 10.0


def test_gate_keeps_stripe_free_frames_and_opens_for_stripes():
    """The default (gated) stage returns a stripe-free frame bit for bit, and on a striped frame
    does what the ungated stage does."""
    d, a = _striped_frames([])
    gated = suppression_from_design()
    torch.testing.assert_close(gated(d, a), d, rtol=0, atol=0)
    s, _ = _striped_frames([2 * math.pi / 3, math.pi])
    ungated = suppression_from_design(gate=False)
    torch.testing.assert_close(gated(s, a), ungated(s, a), rtol=0, atol=1e-12)
    weak = d + 1e-4 * torch.cos(math.pi * torch.arange(d.shape[-1], dtype=d.dtype))
    torch.testing.assert_close(gated(weak, a), weak, rtol=0, atol=0)  # under the floor
