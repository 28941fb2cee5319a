"""FPNFilter: references (SciPy, OpenCV, NumPy float64), borders, delay, invalid pixels, script,
autograd, errors."""

from __future__ import annotations

import importlib
import math

import cv2
import numpy as np
import pytest
import scipy.ndimage as ndi
import torch

from tof_fpn_torch import FPNFilter, design_fpn
from tof_fpn_torch.build import filter_from_design, suppression_from_design
from tof_fpn_torch.design import half_sample_taps, zero_phase_response
from tof_fpn_torch.runtime import fpn_filter, valid_mask
from tof_fpn_torch.runtime.fir import fir_last, fir_operators, fir_polyphase

# the module, not the function of the same name that the package exports
fpn_filter_module = importlib.import_module("tof_fpn_torch.runtime.fpn_filter")
fir_module = importlib.import_module("tof_fpn_torch.runtime.fir")

SCIPY_MODE = {"reflect": "mirror", "replicate": "nearest", "circular": "wrap", "zeros": "constant"}


def fir(x, taps, dim, border="reflect", fast=True):
    """The bare FIR kernel along one axis (no validity handling: signed test data pass as is)."""
    taps = torch.as_tensor(taps)
    if dim == -1:
        return fir_last(x, taps, border, [], fast)
    return fir_last(x.transpose(-1, -2).contiguous(), taps, border, [], fast).transpose(-1, -2)


@pytest.fixture(scope="module")
def design41():
    return design_fpn(41, 0.12)


@pytest.fixture(scope="module")
def design20():
    return design_fpn(20, 0.14)


def _scene(b, h, w, seed=0, dtype=torch.float64):
    """Smooth positive depth scene (metres)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(
        torch.linspace(0, 1, h, dtype=dtype), torch.linspace(0, 1, w, dtype=dtype), indexing="ij"
    )
    phase = torch.rand(b, 1, 1, 1, generator=g, dtype=dtype)
    return 2.0 + 0.8 * torch.sin(2.5 * xx + phase) * torch.cos(1.7 * yy) + 0.3 * yy


@pytest.mark.parametrize("border", list(SCIPY_MODE))
@pytest.mark.parametrize("order", [20, 41])
@pytest.mark.parametrize("width", [1, 2, 5, 20, 41, 42, 63, 200])
def test_matches_scipy_convolve1d(border, order, width, design20, design41):
    taps = (design20 if order == 20 else design41).taps
    g = torch.Generator().manual_seed(width)
    x = torch.randn(2, 3, 9, width, generator=g, dtype=torch.float64)
    ref = ndi.convolve1d(x.numpy(), taps, axis=-1, mode=SCIPY_MODE[border])
    for fast in (True, False):
        y = fir(x, torch.from_numpy(taps), -1, border, fast)
        np.testing.assert_allclose(y.numpy(), ref, rtol=0, atol=1e-12)
    ref_h = ndi.convolve1d(x.numpy(), taps, axis=-2, mode=SCIPY_MODE[border])
    y = fir(x, torch.from_numpy(taps), -2, border, True)
    np.testing.assert_allclose(y.numpy(), ref_h, rtol=0, atol=1e-12)


@pytest.mark.parametrize("border", list(SCIPY_MODE))
@pytest.mark.parametrize("order", [1, 2, 20, 41])
@pytest.mark.parametrize("shape", [(1, 1, 1, 42), (2, 3, 5, 43), (1, 2, 7, 63), (3, 1, 17, 200)])
def test_polyphase_path_matches_scipy(border, order, shape, design20, design41):
    """float32 inference path (polyphase conv + seam GEMM) against SciPy in float64: every
    border mode, widths down to L, batch sizes with ``R W`` not a multiple of the phase count
    (tail), one row only, and the degenerate 2- and 3-tap filters."""
    taps = {1: np.array([0.6, 0.4]), 2: np.array([0.3, 0.5, 0.2])}.get(order)
    if taps is None:
        taps = (design20 if order == 20 else design41).taps
    assert shape[-1] >= taps.size  # every shape reaches the polyphase path (width >= L)
    g = torch.Generator().manual_seed(shape[-1])
    x = 1.0 + torch.rand(shape, generator=g)
    ref = ndi.convolve1d(x.double().numpy(), taps, axis=-1, mode=SCIPY_MODE[border])
    t = torch.from_numpy(taps)
    with torch.inference_mode():
        y = fir(x, t, -1, border, True)
        direct = None
        if x.numel() >= 2 * fir_module._phases():
            direct = fir_polyphase(
                x.reshape(-1, shape[-1]), t.flip(0).float(), border, fir_operators(t, border)
            )
    assert y.dtype == torch.float32
    np.testing.assert_allclose(y.double().numpy(), ref, rtol=0, atol=2e-6)
    if x.numel() >= 2 * fir_module._phases():  # the polyphase path needs 2 P samples
        np.testing.assert_array_equal(direct.reshape(shape).numpy(), y.numpy())
    ref_h = ndi.convolve1d(x.double().numpy(), taps, axis=-2, mode=SCIPY_MODE[border])
    if shape[-2] >= taps.size:
        with torch.inference_mode():
            y = fir(x, t, -2, border, True)
        np.testing.assert_allclose(y.double().numpy(), ref_h, rtol=0, atol=2e-6)


def test_two_tap_reflect_fast_paths():
    """Regression: with L = 2 the reflected right neighbour of the last column is column W - 2,
    outside the last L - 1 columns; both inference paths (float32 polyphase, float64 GEMM)."""
    taps = torch.tensor([0.6, 0.4], dtype=torch.float64)
    x = 1.0 + torch.rand(2, 1, 3, 50, dtype=torch.float64)
    ref = ndi.convolve1d(x.numpy(), taps.numpy(), axis=-1, mode="mirror")
    with torch.inference_mode():
        y64 = fir(x, taps, -1, "reflect", True)
        y32 = fir(x.float(), taps, -1, "reflect", True)
    np.testing.assert_allclose(y64.numpy(), ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(y32.double().numpy(), ref, rtol=0, atol=1e-6)


def test_float32_matches_float64_numpy_reference(design41):
    x64 = _scene(4, 60, 256) + 0.05 * torch.randn(4, 1, 60, 256, dtype=torch.float64)
    ref = ndi.convolve1d(x64.numpy(), design41.taps, axis=-1, mode="mirror")
    f = FPNFilter(design41.taps, allow_shift=True)
    with torch.inference_mode():
        y = f(x64.float())
    assert y.dtype == torch.float32
    err = np.abs(y.double().numpy() - ref).max()
    assert err <= 1e-5, err


def test_matches_opencv_filter2d(design41):
    x = _scene(1, 50, 300).float() + 0.01 * torch.randn(1, 1, 50, 300)
    taps = design41.taps
    kernel = taps[::-1].astype(np.float32).reshape(1, -1).copy()
    anchor = (taps.size - 1 - taps.size // 2, 0)  # cv2 correlates; same centring as convolve1d
    ref = cv2.filter2D(
        x[0, 0].numpy(), -1, kernel, anchor=anchor, borderType=cv2.BORDER_REFLECT_101
    )
    y = FPNFilter(taps, allow_shift=True)(x)[0, 0].numpy()
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-5)


def test_dims_both_is_sequential(design20):
    x = _scene(2, 40, 50) + 0.1 * torch.randn(2, 1, 40, 50, dtype=torch.float64)
    taps = torch.from_numpy(design20.taps)
    both = FPNFilter(taps, dim=(-2, -1))(x)
    seq = FPNFilter(taps, dim=-2)(FPNFilter(taps, dim=-1)(x))
    torch.testing.assert_close(both, seq, rtol=0, atol=1e-12)
    rows = FPNFilter(taps, dim=-2)(x)
    cols_t = FPNFilter(taps, dim=-1)(x.transpose(-1, -2).contiguous()).transpose(-1, -2)
    torch.testing.assert_close(rows, cols_t, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("order", [20, 41])
def test_stripes_drop_60db_away_from_borders(order, dtype):
    f = filter_from_design(order, 0.12)
    h, w = 64, 384
    n = torch.arange(w, dtype=torch.float64)
    stripes = 0.05 * torch.cos(2 * math.pi / 3 * n + 0.4) + 0.03 * torch.cos(math.pi * n)
    scene = _scene(2, h, w)
    with torch.inference_mode():
        y_striped = f((scene + stripes).to(dtype)).double()
        y_clean = f(scene.to(dtype)).double()
    m = f.taps.numel()
    residual = (y_striped - y_clean)[..., m:-m]
    ratio_db = 10 * math.log10(residual.pow(2).mean() / stripes.pow(2).mean())
    # float32: bounded by rounding of the ~2 m scene (eps 1.2e-7 * 2 m vs 0.04 m stripes ~ -100 dB)
    assert ratio_db <= -60.0, ratio_db
    # without the notches the same energy measure is ~0 dB: the measure can fail
    identity = FPNFilter([1.0])
    with torch.inference_mode():
        kept = (identity(scene + stripes) - identity(scene))[..., m:-m]
    assert 10 * math.log10(kept.pow(2).mean() / stripes.pow(2).mean()) > -1.0


@pytest.mark.parametrize("order", [20, 28, 41])
def test_passband_signal_passes_with_designed_ripple(order):
    rho = 0.13
    f = filter_from_design(order, rho, compensate_delay=False, allow_shift=True)
    design = f.design
    w = 600
    n = torch.arange(w, dtype=torch.float64)
    worst = 0.0
    for lo, hi in design.bands:
        for omega in np.linspace(lo, hi, 7):
            x = (3.0 + torch.cos(omega * n + 0.3)).expand(1, 1, 4, w)
            y = f(x.contiguous())
            m = f.taps.numel()
            dc, gain_expected = zero_phase_response(design.taps, np.array([0.0, omega]))
            expected = 3.0 * dc + gain_expected * torch.cos(omega * (n + f.delay) + 0.3)
            err = (y[..., m:-m] - expected[m:-m]).abs().max().item()
            assert err < 1e-9, (omega, err)
            worst = max(worst, abs(gain_expected - 1.0))
    assert worst <= design.ripple * (1 + 1e-9)
    assert worst >= 0.5 * design.ripple  # the probes do reach the ripple


def test_constant_image_gets_dc_gain_all_borders_and_narrow():
    f = filter_from_design(20, 0.14)
    assert abs(float(f.taps.sum()) - 1.0) <= f.design.ripple * (1 + 1e-9)
    for border in ("reflect", "replicate", "circular"):
        g = FPNFilter(f.taps, border=border)
        for w in (1, 3, 21, 64):
            x = torch.full((1, 1, 5, w), 2.5)
            dc = float(f.taps.sum())  # H(0): within the designed ripple of 1
            torch.testing.assert_close(g(x), x * dc, rtol=0, atol=1e-5)


def test_half_sample_delay_reported_and_compensated():
    odd = filter_from_design(41, 0.12, compensate_delay=False, allow_shift=True)
    even = filter_from_design(40, 0.12)
    assert odd.delay == 0.5 and odd.order == 41 and not odd.compensated
    assert even.delay == 0.0
    with pytest.raises(ValueError, match="shift the output by half a sample"):
        filter_from_design(41, 0.12, compensate_delay=False)
    comp = filter_from_design(41, 0.12)  # compensated by default
    assert comp.compensated and comp.delay == 0.0 and comp.order == 41
    assert comp.taps.numel() % 2 == 1
    w = 400
    n = torch.arange(w, dtype=torch.float64)
    omega = 0.3
    x = (2.0 + torch.cos(omega * n)).expand(1, 1, 2, w).contiguous()
    m = comp.taps.numel()
    taps_c = comp.taps.numpy()
    h0, hw = zero_phase_response(odd.taps.numpy(), np.array([0.0, omega]))
    c0, cw = zero_phase_response(taps_c, np.array([0.0, omega]))
    # uncompensated: exactly the zero-phase response, half a sample late
    late = (odd(x) - (2.0 * h0 + hw * torch.cos(omega * (n + 0.5))))[..., m:-m].abs().max()
    on_grid = (odd(x) - (2.0 * h0 + hw * torch.cos(omega * n)))[..., m:-m].abs().max()
    assert late < 1e-9 and on_grid > 0.1
    # compensated: on the input grid, and its response stays within 1e-3 of the original's
    aligned = (comp(x) - (2.0 * c0 + cw * torch.cos(omega * n)))[..., m:-m].abs().max()
    assert aligned < 1e-9
    assert abs(cw - hw) < 1e-3 and abs(c0 - h0) < 1e-3


def test_half_sample_taps_fit():
    d = half_sample_taps(32, 0.8 * math.pi)
    omega = np.linspace(0, 0.8 * math.pi, 500)
    assert np.allclose(d, d[::-1])
    assert np.abs(zero_phase_response(d, omega) - 1).max() < 1e-4


def test_fast_path_equals_autograd_path(design41):
    x = _scene(3, 50, 300).float() + 0.01 * torch.randn(3, 1, 50, 300)
    taps = torch.from_numpy(design41.taps)
    for border in SCIPY_MODE:
        with torch.inference_mode():
            fast = fir(x, taps, -1, border, True)
        slow = fir(x, taps, -1, border, False)
        torch.testing.assert_close(fast, slow, rtol=0, atol=2e-6)


def test_invalid_pixels_do_not_smear_and_stay_invalid(design20):
    f = FPNFilter(design20.taps)
    x = (_scene(1, 30, 200) + 0.002 * torch.randn(1, 1, 30, 200, dtype=torch.float64)).float()
    ref = f(x)
    holes = x.clone()
    holes[0, 0, 5, 100] = float("nan")
    holes[0, 0, 10, 60:66] = 0.0
    holes[0, 0, 20, :] = float("nan")  # a whole row
    mask = torch.ones_like(x, dtype=torch.bool)
    mask[0, 0, 25, 150:153] = False
    y = f(holes, mask)
    assert torch.isnan(y[0, 0, 5, 100]) and torch.isnan(y[0, 0, 20]).all()
    assert (y[0, 0, 10, 60:66] == 0).all()
    torch.testing.assert_close(y[0, 0, 25, 150:153], holes[0, 0, 25, 150:153])
    invalid = ~valid_mask(holes, mask=mask)
    assert torch.isfinite(y[~invalid]).all() and (y[~invalid] != 0).all()
    err = (y - ref).abs()[~invalid]
    naive = fir(torch.nan_to_num(holes) * mask, f.taps, -1, "reflect", True)
    naive_err = (naive - ref).abs()[~invalid]
    assert err.max() < 0.05 * naive_err.max()
    assert err.max() < 0.02  # metres: the filled values are interpolated from valid neighbours
    far = torch.ones_like(x, dtype=torch.bool)
    far[0, 0, [5, 10, 20, 25]] = False  # float32 rounding: the hole path sums in another order
    torch.testing.assert_close(y[far], ref[far], rtol=0, atol=2e-6)


@pytest.mark.parametrize(
    "value", [math.nan, -math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e-42, 3e38]
)
def test_fast_validity_check_special_values(value, design20):
    """The float32 fast check tests bit patterns (0 < bits < +inf's): NaN of either sign, +-inf,
    +-0, negatives, denormals and huge values must take the same decision as the full path."""
    f = FPNFilter(design20.taps)
    x = 1.0 + torch.rand(1, 1, 8, 64, generator=torch.Generator().manual_seed(0))
    x[0, 0, 3, 10] = value
    y = f(x)
    with pytest.MonkeyPatch.context() as mp:  # the traced path: always the full validity mask
        mp.setattr(fpn_filter_module, "_tracing", lambda: True)
        ref = f(x)
    torch.testing.assert_close(y, ref, rtol=0, atol=2e-6, equal_nan=True)
    assert torch.equal(y.isnan(), x.isnan())


def test_torchscript_matches_eager(design41):
    for dim in (-1, -2, (-2, -1)):
        f = FPNFilter(design41.taps, dim=dim, allow_shift=True)
        s = torch.jit.script(f)
        x = _scene(2, 40, 60).float()
        torch.testing.assert_close(s(x), f(x), rtol=0, atol=0)
        x[0, 0, 3, 4] = float("nan")
        x[1, 0, 7, 9:12] = 0.0
        torch.testing.assert_close(s(x), f(x), rtol=0, atol=0, equal_nan=True)


def test_gradcheck_float64_input_and_taps(design20):
    x = _scene(1, 3, 14) + 0.1 * torch.randn(1, 1, 3, 14, dtype=torch.float64)
    x.requires_grad_(True)
    f = FPNFilter(design20.taps, dim=(-2, -1))
    assert torch.autograd.gradcheck(lambda t: f(t), (x,))
    taps = torch.from_numpy(design20.taps).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t, h: fpn_filter(t, h, -1), (x, taps))


def test_trainable_taps_are_parameters_initialised_from_design(design20):
    f = filter_from_design(20, 0.14, trainable=True)
    assert isinstance(f.taps, torch.nn.Parameter)
    np.testing.assert_allclose(f.taps.detach().numpy(), design20.taps, atol=1e-7)
    x = _scene(2, 16, 40).float() + 0.1 * torch.randn(2, 1, 16, 40)
    target = _scene(2, 16, 40).float()
    opt = torch.optim.SGD(f.parameters(), lr=0.1)
    before = f.taps.detach().clone()
    loss = (f(x) - target).pow(2).mean()
    loss.backward()
    assert f.taps.grad is not None and f.taps.grad.abs().sum() > 0
    opt.step()
    assert not torch.equal(before, f.taps.detach())
    fixed = filter_from_design(20, 0.14)
    assert "taps" in dict(fixed.named_buffers()) and not list(fixed.parameters())


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_runs_in_float32(dtype, design20):
    x = _scene(1, 20, 80).float()
    ref = FPNFilter(design20.taps)(x)
    y = FPNFilter(design20.taps)(x.to(dtype))
    assert y.dtype == dtype
    eps = torch.finfo(dtype).eps
    # input rounding (eps/2 * |x| * sum|h|) plus output rounding (eps/2 * |y|)
    bound = eps * 3.0 * (1 + np.abs(design20.taps).sum())
    assert (y.float() - ref).abs().max().item() <= bound


def test_errors_name_what_was_given(design20):
    f = FPNFilter(design20.taps)
    with pytest.raises(ValueError, match=r"\(B, C, H, W\).*3 dimensions"):
        f(torch.zeros(1, 4, 4))
    with pytest.raises(ValueError, match="floating-point.*torch.int64"):
        f(torch.zeros(1, 1, 4, 4, dtype=torch.int64))
    with pytest.raises(ValueError, match="mask must have the shape"):
        f(torch.ones(1, 1, 4, 4), torch.ones(1, 1, 4, 5, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"finite.*indices \[1\]"):
        FPNFilter([0.5, float("nan"), 0.5])
    with pytest.raises(ValueError, match="border must be one of"):
        FPNFilter(design20.taps, border="mirror")
    with pytest.raises(ValueError, match="dim must be"):
        FPNFilter(design20.taps, dim=1)
    with pytest.raises(ValueError, match="1-D"):
        FPNFilter(np.ones((2, 2)))


def test_modules_can_be_built_and_run_in_inference_mode(design20):
    """Building the stage inside ``torch.inference_mode()`` (a serving process that never needs
    autograd) works and gives the same output as a module built outside it."""
    x = _scene(1, 8, 40).float()
    ref = FPNFilter(design20.taps)(x)
    with torch.inference_mode():
        f = FPNFilter(design20.taps)
        torch.testing.assert_close(f(x), ref, rtol=0, atol=0)
        stage = suppression_from_design()
        assert stage(x, torch.full_like(x, 100.0)).shape == x.shape
