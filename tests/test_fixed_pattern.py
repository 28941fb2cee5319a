"""calibrate_fixed_pattern / FixedPattern (.npz) / FixedPatternCorrection (TorchScript, ONNX)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tof_fpn_torch import constants as K
from tof_fpn_torch.analysis.calibrate import MIN_PIXEL_FRAMES, calibrate_fixed_pattern
from tof_fpn_torch.clean.pattern import read_pattern, save_pattern
from tof_fpn_torch.export import export_onnx, export_torchscript
from tof_fpn_torch.runtime import FixedPatternCorrection
from tof_fpn_torch.runtime._destripe_core import highpass

H, W = 64, 96


def _corr(a, b) -> float:
    return float(np.corrcoef(a.flatten().numpy(), b.flatten().numpy())[0, 1])


def _hp(v: torch.Tensor) -> torch.Tensor:
    return highpass(v[None, None], K.DESTRIPE_WIDTH)[0, 0]


@pytest.fixture(scope="module")
def pattern():
    g = torch.Generator().manual_seed(0)
    return {
        "c": 0.004 * torch.randn(W, generator=g, dtype=torch.float64),
        "r": 0.002 * torch.randn(H, generator=g, dtype=torch.float64),
        "p": 0.003 * torch.randn(H, W, generator=g, dtype=torch.float64),
        "gamma": 0.01 * torch.randn(W, generator=g, dtype=torch.float64),
    }


def _flat_field(pattern, frames=16, level=1.5, gain=False, seed=1, noise=0.01):
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(
        torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij"
    )
    scene = level + 0.002 * xx + 0.001 * yy + 1e-5 * (xx - 40) ** 2  # a smooth, tilted target
    if gain:
        scene = (1 + pattern["gamma"]) * scene
    fixed = pattern["c"] + pattern["r"][:, None] + pattern["p"]
    t = torch.randn(frames, 1, H, W, generator=g, dtype=torch.float64)
    return (scene + fixed + noise * t).float(), scene


def test_recovers_column_row_and_pixel_offsets(pattern):
    frames, _ = _flat_field(pattern)
    fp = calibrate_fixed_pattern(frames, flat_field=True)
    assert fp.shape == (H, W) and fp.frames == 16 and fp.groups == 1
    assert _corr(fp.column_offset, _hp(pattern["c"])) > 0.95
    assert _corr(fp.row_offset, _hp(pattern["r"])) > 0.9
    # per pixel: SE = 0.01 / 4 against a 3 mm pattern, so the best possible correlation is ~0.77
    assert _corr(fp.pixel_offset, pattern["p"]) > 0.6
    assert fp.column_gain is None
    se = float(fp.column_se.mean())
    assert 0.3 * 0.01 / (4 * 8) < se < 3 * 0.01 / (4 * 8)  # sigma / sqrt(T * H)
    # the correction leaves less than the pattern's high-passed part
    out = fp.module()(frames)
    fixed = pattern["c"] + pattern["r"][:, None] + pattern["p"]
    before = (frames.double() - frames.double().mean(0)).std() ** 2  # temporal noise only
    after_fixed = float((out.double().mean(0) - frames.double().mean(0) + fixed).std())
    assert after_fixed < 0.75 * float(fixed.std()), (after_fixed, float(before))


def test_pixel_offsets_need_flat_field_and_frames(pattern):
    frames, _ = _flat_field(pattern, frames=MIN_PIXEL_FRAMES - 1)
    assert calibrate_fixed_pattern(frames, flat_field=True).pixel_offset is None
    frames, _ = _flat_field(pattern, frames=MIN_PIXEL_FRAMES)
    assert calibrate_fixed_pattern(frames).pixel_offset is None
    assert calibrate_fixed_pattern(frames, flat_field=True).pixel_offset is not None


def test_no_pattern_gives_small_offsets():
    g = torch.Generator().manual_seed(3)
    frames = 2.0 + 0.01 * torch.randn(12, 1, H, W, generator=g, dtype=torch.float64)
    fp = calibrate_fixed_pattern(frames, flat_field=True)
    assert float(fp.column_offset.abs().max()) < 0.002  # noise of a column mean: 0.01 / 28
    assert float(fp.pixel_offset.abs().max()) < 0.002  # JS-shrunk to (almost) nothing


def test_column_gain_from_two_distances(pattern):
    a, _ = _flat_field(pattern, frames=8, level=1.0, gain=True, seed=4, noise=0.005)
    b, _ = _flat_field(pattern, frames=8, level=2.5, gain=True, seed=5, noise=0.005)
    fp = calibrate_fixed_pattern(torch.cat([a, b]), groups=[0] * 8 + [1] * 8)
    assert fp.groups == 2 and len(fp.levels) == 2
    assert _corr(fp.column_gain - 1.0, _hp(pattern["gamma"])) > 0.95
    assert _corr(fp.column_offset, _hp(pattern["c"])) > 0.9


def test_save_load_roundtrip_and_numpy_reads_it(tmp_path, pattern):
    frames, _ = _flat_field(pattern)
    fp = calibrate_fixed_pattern(frames, flat_field=True)
    path = save_pattern(fp, tmp_path / "sub" / "pattern.npz")
    back = read_pattern(path)
    for name in ("column_offset", "row_offset", "pixel_offset", "column_se"):
        assert torch.equal(getattr(back, name), getattr(fp, name)), name
    assert back.column_gain is None and back.frames == fp.frames and back.levels == fp.levels
    with np.load(path, allow_pickle=False) as z:
        assert set(z.files) >= {"column_offset", "row_offset", "pixel_offset", "column_gain"}
        np.testing.assert_array_equal(z["pixel_offset"], fp.pixel_offset.numpy())
        np.testing.assert_array_equal(z["column_gain"], np.ones(W))
        meta = z["meta_json"].tobytes().decode()
    assert '"has_pixel": true' in meta and '"has_gain": false' in meta
    bad = tmp_path / "bad.npz"
    np.savez(bad, column_offset=np.zeros(3))
    with pytest.raises(ValueError, match="not a fixed-pattern file: missing"):
        read_pattern(bad)


def test_correction_formula_and_invalid_pixels():
    m = FixedPatternCorrection([0.0, 0.5, -0.5], [0.1, 0.2], column_gain=[1.0, 2.0, 1.0])
    d = torch.full((1, 1, 2, 3), 2.0, dtype=torch.float64)
    expect = torch.tensor([[1.9, 0.7, 2.4], [1.8, 0.65, 2.3]], dtype=torch.float64)
    torch.testing.assert_close(m(d)[0, 0], expect, rtol=0, atol=1e-12)
    d[0, 0, 0, 0], d[0, 0, 1, 1], d[0, 0, 1, 2] = float("nan"), 0.0, -3.0
    a = torch.full_like(d, 10.0)
    a[0, 0, 0, 1] = -1.0
    out = m(d, a)
    assert torch.isnan(out[0, 0, 0, 0]) and out[0, 0, 1, 1] == 0 and out[0, 0, 1, 2] == -3
    assert out[0, 0, 0, 1] == 2.0 and abs(float(out[0, 0, 0, 2]) - 2.4) < 1e-12


def test_correction_errors():
    with pytest.raises(ValueError, match=r"column_offset must be a 1-D tensor, got shape \[2, 2\]"):
        FixedPatternCorrection(torch.zeros(2, 2))
    with pytest.raises(ValueError, match="column_gain must be > 0"):
        FixedPatternCorrection(torch.zeros(3), column_gain=[1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match=r"row_offset must be a 1-D tensor of 4 values"):
        FixedPatternCorrection(torch.zeros(3), torch.zeros(5), torch.zeros(4, 3))
    m = FixedPatternCorrection(torch.zeros(3), torch.zeros(4))
    with pytest.raises(ValueError, match=r"calibrated size \(\.\.\., 4, 3\), got shape"):
        m(torch.ones(1, 1, 4, 5))


def test_calibration_errors(pattern):
    frames, _ = _flat_field(pattern, frames=4)
    with pytest.raises(ValueError, match=r"frames must be a \(T, 1, H, W\) tensor"):
        calibrate_fixed_pattern(frames[:, 0])
    with pytest.raises(ValueError, match="T >= 2 frames"):
        calibrate_fixed_pattern(frames[:1])
    with pytest.raises(ValueError, match="every group needs >= 2 frames, group 1 has 1"):
        calibrate_fixed_pattern(frames, groups=[0, 0, 0, 1])
    with pytest.raises(ValueError, match="one label per frame"):
        calibrate_fixed_pattern(frames, groups=[0, 0])
    with pytest.raises(ValueError, match="different mean depths"):
        calibrate_fixed_pattern(torch.cat([frames, frames]), groups=[0] * 4 + [1] * 4)
    with pytest.raises(ValueError, match="width must be an int >= 3, got 1"):
        calibrate_fixed_pattern(frames, width=1)


def _inputs(seed=0):
    g = torch.Generator().manual_seed(seed)
    d = 1.0 + torch.rand(2, 1, H, W, generator=g)
    a = 100.0 * torch.rand(2, 1, H, W, generator=g)
    d[0, 0, 3, 4] = float("nan")
    d[1, 0, 5, 6:9] = 0.0
    d[1, 0, 7, 7] = -2.0
    a[0, 0, 9, 9] = -1.0
    return d, a


@pytest.fixture(scope="module")
def module(pattern):
    a, _ = _flat_field(pattern, frames=10, level=1.0, gain=True, seed=6)
    b, _ = _flat_field(pattern, frames=10, level=2.0, gain=True, seed=7)
    fp = calibrate_fixed_pattern(torch.cat([a, b]), groups=[0] * 10 + [1] * 10, flat_field=True)
    assert fp.pixel_offset is not None and fp.column_gain is not None
    return fp.module()


def test_torchscript_export_matches_eager(tmp_path, module):
    path = tmp_path / "fp.pt"
    export_torchscript(module, path)
    loaded = torch.jit.load(str(path))
    d, a = _inputs()
    ref = module(d, a)
    out = loaded(d, a)
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-5, equal_nan=True)
    assert torch.isnan(out[0, 0, 3, 4]) and bool((out[1, 0, 5, 6:9] == 0).all())


def test_onnx_export_matches_eager_and_keeps_invalid_invalid(tmp_path, module):
    ort = pytest.importorskip("onnxruntime")
    d, a = _inputs(1)
    path = export_onnx(module, tmp_path / "fp.onnx", example_inputs=(d, a), dynamic=False)
    sess = ort.InferenceSession(str(path))
    out = sess.run(None, {"depth": d.numpy(), "amplitude": a.numpy()})[0]
    ref = module(d, a).numpy()
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5)
    assert np.isnan(out[0, 0, 3, 4]) and (out[1, 0, 5, 6:9] == 0).all() and out[1, 0, 7, 7] == -2
    assert out[0, 0, 9, 9] == d[0, 0, 9, 9].item()
    d2, a2 = _inputs(2)  # another frame through the same graph
    out2 = sess.run(None, {"depth": d2.numpy(), "amplitude": a2.numpy()})[0]
    np.testing.assert_allclose(out2, module(d2, a2).numpy(), rtol=0, atol=1e-5)


def test_a_valid_pixel_never_comes_out_invalid():
    m = FixedPatternCorrection([0.5, 0.0])
    out = m(torch.tensor([[[[0.3, 0.3]]]], dtype=torch.float64))
    assert out.tolist() == [[[[0.3, 0.3]]]]
