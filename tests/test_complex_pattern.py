"""calibrate_complex_pattern / ComplexPattern (.npz) / ComplexPatternCorrection (TorchScript, ONNX)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.analysis import calibrate_complex_pattern
from tof_fpn_torch.analysis.metrics import psnr
from tof_fpn_torch.clean.pattern import read_pattern, save_pattern
from tof_fpn_torch.export import export_onnx, export_torchscript
from tof_fpn_torch.runtime import ComplexPatternCorrection
from tof_fpn_torch.runtime._destripe_core import highpass

F0 = K.CAMCUBE_MODULATION_FREQUENCY_HZ
SCALE = K.SPEED_OF_LIGHT_AIR / (4 * math.pi * F0)  # metres per radian
RANGE = 2 * math.pi * SCALE
H, W = 64, 96


def _corr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(np.corrcoef(a.flatten().numpy(), b.flatten().numpy())[0, 1])


def _scenes(t: int, seed: int):
    """``t`` different scenes: a slanted wall with boxes at other depths, amplitudes 15-90 with
    a vertical texture on the boxes."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(
        torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij"
    )
    depth, amp = [], []
    for _ in range(t):
        d = 3.0 + 0.01 * xx + 0.005 * yy + 0.5 * torch.rand(1, generator=g, dtype=torch.float64)
        a = 40.0 + 20.0 * torch.rand(1, generator=g, dtype=torch.float64) - 0.1 * yy
        for _ in range(3):
            y0, x0 = (int(v) for v in torch.randint(0, 40, (2,), generator=g))
            box = (yy >= y0) & (yy < y0 + 20) & (xx >= x0) & (xx < x0 + 30)
            d = torch.where(box, 1.0 + 4.0 * torch.rand(1, generator=g, dtype=torch.float64), d)
            a = torch.where(box, 60.0 + 30.0 * torch.cos(xx / 3.0), a)
        depth.append(d)
        amp.append(a)
    return torch.stack(depth)[:, None], torch.stack(amp)[:, None]


def _measure(depth, amp, pattern, seed: int, noise: float = 2.0, rows=None):
    """Depth and amplitude of ``z = A e^{j phi} + c(x) [+ r(y)] + noise`` (as a camera reports)."""
    g = torch.Generator().manual_seed(seed)
    z = amp * torch.exp(1j * depth / SCALE)
    if pattern is not None:
        z = z + torch.complex(pattern[0], pattern[1]).view(1, 1, 1, -1)
    if rows is not None:
        z = z + torch.complex(rows[0], rows[1]).view(1, 1, -1, 1)
    e = torch.randn((2, *z.shape), generator=g, dtype=torch.float64)
    z = z + noise * torch.complex(e[0], e[1])  # noise per channel
    return torch.remainder(torch.angle(z), 2 * math.pi) * SCALE, z.abs()


@pytest.fixture(scope="module")
def pattern():
    g = torch.Generator().manual_seed(7)
    return 4.0 * torch.randn(2, W, generator=g, dtype=torch.float64)


@pytest.fixture(scope="module")
def calibrated(pattern):
    d, a = _measure(*_scenes(16, seed=1), pattern, seed=2)
    return calibrate_complex_pattern(d.float(), a.float(), F0)


def test_recovers_an_injected_complex_pattern(pattern, calibrated):
    est = torch.stack([calibrated.column_offset_re, calibrated.column_offset_im])
    truth = highpass(pattern[None], W // 4)[0]  # what a high-pass over W / 4 columns can keep
    assert _corr(est, truth) > 0.97
    assert calibrated.shrink_factor > 0.9 and calibrated.frames == 16
    assert calibrated.shape == (H, W) and calibrated.row_offset_re is None
    assert 1.8 < calibrated.noise_sigma < 2.2  # the injected 2.0 per channel
    # a held-out frame of another scene: most of what the true pattern's removal gains (measured
    # +5.7 dB of +7.5; the rest is the part slower than the W / 4 = 24-column high-pass)
    gt, amp = _scenes(1, seed=5)
    d, a = _measure(gt, amp, pattern, seed=6)
    out = calibrated.module()(d.float(), a.float()).double()
    ideal = ComplexPatternCorrection(pattern[0], pattern[1], F0)(d, a)
    before, after, best = (float(psnr(x, gt, d_max=RANGE)[0]) for x in (d, out, ideal))
    assert after > before + 4.5 and after > best - 2.5, (before, after, best)


def test_no_pattern_gives_almost_nothing():
    """A camera without the pattern: the cross-validated shrinkage keeps (almost) nothing. What it
    keeps is the part of the scenes' slow column profile common to both halves that the high-pass
    leaves (the slanted walls rotate ``z`` along the rows), ~2 % of the pattern of the test above;
    the depth of a held-out frame moves by a few percent of its noise."""
    d, a = _measure(*_scenes(16, seed=3), None, seed=4)
    cp = calibrate_complex_pattern(d, a, F0)
    est = torch.stack([cp.column_offset_re, cp.column_offset_im])
    assert float(est.pow(2).sum(0).mean().sqrt()) < 0.15  # the pattern above: 5.7
    gt, amp = _scenes(1, seed=5)
    d1, a1 = _measure(gt, amp, None, seed=6)
    out = cp.module()(d1, a1)
    moved = float((out - d1).pow(2).mean().sqrt())
    assert moved < 0.05 * float((d1 - gt).pow(2).mean().sqrt())
    change = float(psnr(out, gt, d_max=RANGE)[0] - psnr(d1, gt, d_max=RANGE)[0])
    assert abs(change) < 0.05


def test_rows_are_recovered_when_asked(pattern):
    g = torch.Generator().manual_seed(11)
    rows = 3.0 * torch.randn(2, H, generator=g, dtype=torch.float64)
    d, a = _measure(*_scenes(16, seed=1), pattern, seed=12, rows=rows)
    cp = calibrate_complex_pattern(d, a, F0, rows=True)
    est = torch.stack([cp.row_offset_re, cp.row_offset_im])
    assert _corr(est, highpass(rows[None], H // 4)[0]) > 0.9
    col = torch.stack([cp.column_offset_re, cp.column_offset_im])
    assert _corr(col, highpass(pattern[None], W // 4)[0]) > 0.95
    m = cp.module()
    assert m.height == H and m.offset.shape == (1, 2, H, W)


def test_correction_is_the_phase_of_z_minus_the_offset():
    g = torch.Generator().manual_seed(0)
    re, im = torch.randn(W, generator=g).double(), torch.randn(W, generator=g).double()
    d = 0.2 + 7.0 * torch.rand(2, 1, H, W, generator=g, dtype=torch.float64)
    a = 20.0 * torch.rand(2, 1, H, W, generator=g, dtype=torch.float64)
    out = ComplexPatternCorrection(re, im, F0)(d, a)
    z = a * torch.exp(1j * d / SCALE) - torch.complex(re, im)
    expect = torch.remainder(torch.angle(z), 2 * math.pi) * SCALE
    valid = expect > 0
    torch.testing.assert_close(out[valid], expect[valid], rtol=0, atol=1e-9)
    assert out.dtype == torch.float64


def test_depth_along_the_axis_is_corrected_on_the_radial_distance():
    # a camera that writes Z: the phase is that of Z |ray|; reference in NumPy
    g = torch.Generator().manual_seed(1)
    re, im = torch.randn(W, generator=g).double(), torch.randn(W, generator=g).double()
    d = 0.2 + 4.0 * torch.rand(2, 1, H, W, generator=g, dtype=torch.float64)
    a = 5.0 + 20.0 * torch.rand(2, 1, H, W, generator=g, dtype=torch.float64)
    fpx = 9.0
    out = ComplexPatternCorrection(re, im, F0, focal_length_px=fpx, wrap=False)(d, a)
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    ray = np.sqrt(1 + ((xx - (W - 1) / 2) ** 2 + (yy - (H - 1) / 2) ** 2) / fpx**2)
    r = d.numpy() * ray
    z = a.numpy() * np.exp(1j * r / SCALE)
    zc = z - (re.numpy() + 1j * im.numpy())
    expect = (r + SCALE * np.angle(zc * np.conj(z))) / ray
    expect = np.where(expect > 0, expect, d.numpy())  # a valid pixel never comes out invalid
    np.testing.assert_allclose(out.numpy(), expect, rtol=0, atol=1e-9)
    # the radial reading differs from it wherever the ray is long (the corners)
    radial = ComplexPatternCorrection(re, im, F0, wrap=False)(d, a)
    assert float((radial - out)[..., 0, 0].abs().max()) > 1e-3
    # TorchScript agrees
    m = torch.jit.script(ComplexPatternCorrection(re, im, F0, focal_length_px=fpx))
    torch.testing.assert_close(
        m(d, a), ComplexPatternCorrection(re, im, F0, focal_length_px=fpx)(d, a)
    )
    with pytest.raises(ValueError, match="focal_length_px must be a finite number > 0"):
        ComplexPatternCorrection(re, im, F0, focal_length_px=0.0)


def _inputs(seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    d = (0.3 + 7.0 * torch.rand(2, 1, H, W, generator=g)).to(dtype)
    a = (5.0 + 50.0 * torch.rand(2, 1, H, W, generator=g)).to(dtype)
    d[0, 0, 3, 4] = float("nan")
    d[1, 0, 5, 6:9] = 0.0
    d[1, 0, 7, 7] = -2.0
    d[0, 0, 8, 8] = float("inf")
    a[0, 0, 9, 9] = -1.0
    a[1, 0, 10, 10] = float("nan")
    return d, a


_INVALID = [
    (0, 3, 4),
    (1, 5, 6),
    (1, 5, 7),
    (1, 5, 8),
    (1, 7, 7),
    (0, 8, 8),
    (0, 9, 9),
    (1, 10, 10),
]


@pytest.mark.parametrize("dtype", [torch.float16, torch.float32, torch.float64])
def test_invalid_pixels_bit_identical_and_dtype_kept(pattern, dtype):
    m = ComplexPatternCorrection(pattern[0], pattern[1], F0)
    d, a = _inputs(dtype=dtype)
    out = m(d, a)
    assert out.dtype == dtype and out.shape == d.shape
    for b, y, x in _INVALID:
        same = torch.equal(out[b, 0, y, x], d[b, 0, y, x]) or (
            bool(torch.isnan(out[b, 0, y, x])) and bool(torch.isnan(d[b, 0, y, x]))
        )
        assert same, (b, y, x)
    assert bool((out != d).float().mean() > 0.5)


def test_a_valid_pixel_never_comes_out_invalid():
    # a pixel at 1 mm whose phase the offset turns below 0: without wrapping it would be < 0
    d = torch.tensor([[[[0.001, 0.001]]]], dtype=torch.float64)
    a = torch.tensor([[[[10.0, 10.0]]]], dtype=torch.float64)
    m = ComplexPatternCorrection([0.0, 0.0], [0.0, 1.0], F0, wrap=False)
    assert m(d, a).tolist() == d.tolist()
    wrapped = ComplexPatternCorrection([0.0, 0.0], [0.0, 1.0], F0)(d, a)
    assert wrapped[0, 0, 0, 0] == d[0, 0, 0, 0] and 7.0 < float(wrapped[0, 0, 0, 1]) < RANGE


def test_torchscript_export_matches_eager(tmp_path, calibrated):
    module = calibrated.module()
    export_torchscript(module, tmp_path / "cp.pt")
    loaded = torch.jit.load(str(tmp_path / "cp.pt"))
    d, a = _inputs()
    torch.testing.assert_close(loaded(d, a), module(d, a), rtol=0, atol=1e-5, equal_nan=True)


def test_onnx_export_matches_eager_and_keeps_invalid_invalid(tmp_path, calibrated):
    ort = pytest.importorskip("onnxruntime")
    module = calibrated.module()
    d, a = _inputs(1)
    path = export_onnx(module, tmp_path / "cp.onnx", example_inputs=(d, a), dynamic=False)
    sess = ort.InferenceSession(str(path))
    for seed in (1, 2):  # the traced frame and another one through the same graph
        d, a = _inputs(seed)
        out = sess.run(None, {"depth": d.numpy(), "amplitude": a.numpy()})[0]
        ref = module(d, a).numpy()
        np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5)
        for b, y, x in _INVALID:
            assert np.array_equal(out[b, 0, y, x], d.numpy()[b, 0, y, x], equal_nan=True)


def test_save_load_roundtrip_and_numpy_reads_it(tmp_path, pattern):
    d, a = _measure(*_scenes(8, seed=1), pattern, seed=2)
    cp = calibrate_complex_pattern(d, a, F0, rows=True)
    path = save_pattern(cp, tmp_path / "sub" / "pattern.npz")
    back = read_pattern(path)
    for name in ("column_offset_re", "column_offset_im", "row_offset_re", "row_offset_im"):
        assert torch.equal(getattr(back, name), getattr(cp, name)), name
    assert torch.equal(back.column_pixels, cp.column_pixels)
    for name in ("modulation_frequency_hz", "frames", "width", "shrink_factor", "noise_sigma"):
        assert getattr(back, name) == getattr(cp, name), name
    x, y = _inputs()
    torch.testing.assert_close(
        back.module()(x, y), cp.module()(x, y), rtol=0, atol=0, equal_nan=True
    )
    with np.load(path, allow_pickle=False) as z:
        np.testing.assert_array_equal(z["column_offset_im"], cp.column_offset_im.numpy())
        assert z["row_offset_re"].shape == (H,)
        meta = z["meta_json"].tobytes().decode()
    assert '"has_rows": true' in meta and '"format": "tof_fpn_torch.complex_pattern/1"' in meta
    # without rows: the file holds zeros and says so
    cp2 = calibrate_complex_pattern(d, a, F0)
    back2 = read_pattern(save_pattern(cp2, tmp_path / "cols.npz"))
    assert back2.row_offset_re is None and back2.module().height == -1
    bad = tmp_path / "bad.npz"
    np.savez(bad, column_offset_re=np.zeros(3))
    with pytest.raises(ValueError, match="not a complex-pattern file: missing"):
        read_pattern(bad)


def test_errors():
    d, a = _inputs()
    d, a = d[:1], a[:1]
    with pytest.raises(ValueError, match=r"frames must be a \(T, 1, H, W\) tensor"):
        calibrate_complex_pattern(d[:, 0], a, F0)
    with pytest.raises(ValueError, match="amplitudes must have the frames' shape"):
        calibrate_complex_pattern(d, a[..., :5], F0)
    with pytest.raises(ValueError, match=r"modulation_frequency_hz must be a finite number > 0"):
        calibrate_complex_pattern(d, a, 0.0)
    with pytest.raises(ValueError, match="width must be an int >= 3.*got 2"):
        calibrate_complex_pattern(d, a, F0, width=2)
    with pytest.raises(ValueError, match="amplitude_cap must be a finite number > 0, got -1"):
        calibrate_complex_pattern(d, a, F0, amplitude_cap=-1)
    with pytest.raises(ValueError, match="column_offset_im must be a 1-D tensor of 3 values"):
        ComplexPatternCorrection([0.0, 1.0, 2.0], [0.0], F0)
    with pytest.raises(ValueError, match="row_offset_re and row_offset_im must be given together"):
        ComplexPatternCorrection([0.0], [0.0], F0, row_offset_re=[1.0])
    with pytest.raises(ValueError, match="column_offset_re must be finite"):
        ComplexPatternCorrection([math.nan], [0.0], F0)
    m = ComplexPatternCorrection([0.0] * 3, [0.0] * 3, F0, height=4)
    with pytest.raises(ValueError, match=r"calibrated size \(\.\.\., 4, 3\), got shape"):
        m(torch.ones(1, 1, 4, 5), torch.ones(1, 1, 4, 5))
