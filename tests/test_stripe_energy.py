"""The stripe measures of :mod:`tof_fpn_torch.analysis.stripe_energy` and the record of
``tof-fpn clean`` (:mod:`tof_fpn_torch.clean.measure`) computed from cumulative sums equal their
first formulation (dense ``conv2d`` box filters, ``max_pool2d``, ``avg_pool2d``, kept in
``tests/_stripe_energy_ref.py``) up to float rounding, on random frames with NaN holes, an edge
and stripes, at odd sizes."""

from __future__ import annotations

import math

import _stripe_energy_ref as dense
import pytest
import torch
import torch.nn.functional as F

from tof_fpn_torch.analysis.stripe_energy import (
    _dilate,
    _window_sum,
    column_stripe_energy,
    energy_before_after,
    lowpass_change,
    quiet_mask,
    row_highpass,
    structure_mask,
)
from tof_fpn_torch.clean.measure import _frame

SIZES = [(1, 2), (2, 1), (7, 5), (191, 255)]


def _frames(h: int, w: int, seed: int, dtype=torch.float32, batch: int = 1):
    """(before, after): a sloped scene with a 0.3 m step, column stripes, 4 mm noise, 5 % NaN
    holes and, where there are rows to spare, a row with no valid pixel; after = before less
    most of the stripes and with a few more holes."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    scene = 1.5 + 2e-3 * yy + 5e-4 * xx + 0.3 * (xx > w / 3)
    stripes = 6e-3 * torch.cos(math.pi * xx) + 3e-3 * torch.randn(1, w, generator=g)
    noise = 4e-3 * torch.randn(batch, 1, h, w, generator=g, dtype=torch.float64)
    before = scene + stripes + noise
    before[torch.rand(batch, 1, h, w, generator=g) < 0.05] = float("nan")
    if h > 4:
        before[..., 3, :] = float("nan")
    after = before - 0.9 * stripes
    after[torch.rand(batch, 1, h, w, generator=g) < 0.01] = float("nan")
    return before.to(dtype), after.to(dtype)


def _close(a, b, atol):
    torch.testing.assert_close(a.double(), b.double(), rtol=0, atol=atol, equal_nan=True)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("h", "w"), SIZES)
def test_the_filters_equal_their_dense_formulation(h, w, dtype):
    before, _ = _frames(h, w, seed=h * 1000 + w, dtype=dtype, batch=2)
    given = before.clone()
    atol = 1e-12 if dtype == torch.float64 else 1e-8  # a float32 output: an ulp of the high-pass
    for width in (3, 9, 15):
        ref = dense.row_highpass(before, width)
        _close(row_highpass(before, width), ref, atol)
        quiet = dense.quiet_mask(before)
        _close(row_highpass(before, width, quiet), dense.row_highpass(before, width, quiet), atol)
    assert torch.equal(quiet_mask(before), dense.quiet_mask(before))
    for threshold, dilate in ((5e-3, 6), (5e-3, 0), (2e-2, 2)):
        fast = structure_mask(before, threshold, 15, dilate)
        assert torch.equal(fast, dense.structure_mask(before, threshold, 15, dilate))
    for size in (15, 4, 1):
        _, after = _frames(h, w, seed=h * 1000 + w, dtype=dtype, batch=2)
        atol_lp = 1e-12
        _close(
            lowpass_change(before, after, size), dense.lowpass_change(before, after, size), atol_lp
        )
        region = dense.quiet_mask(before)
        _close(
            lowpass_change(before, after, size, region),
            dense.lowpass_change(before, after, size, region),
            atol_lp,
        )
    _close(before, given, 0)  # the input is left as it was


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("h", "w"), [s for s in SIZES if s[0] >= 2])
def test_the_stripe_energy_equals_its_dense_formulation(h, w, dtype):
    before, after = _frames(h, w, seed=7 * h + w, dtype=dtype, batch=2)
    min_rows = 16 if h >= 64 else 1
    quiet = dense.quiet_mask(before)
    for region in (None, quiet):
        fast = column_stripe_energy(before, region, 9, min_rows=min_rows)
        ref = dense.column_stripe_energy(before, region, 9, min_rows=min_rows)
        names = ("covariance", "correlation", "spread", "top", "bottom", "columns")
        for name, r in zip(names, ref, strict=True):
            _close(getattr(fast, name), r, 1e-12 if name != "correlation" else 1e-9)
    eb, ea = energy_before_after(before, after, min_rows=min_rows)
    rb, ra = (
        dense.column_stripe_energy(before, quiet, min_rows=min_rows),
        dense.column_stripe_energy(after, quiet, min_rows=min_rows),
    )
    for fast, ref in ((eb, rb), (ea, ra)):
        _close(fast.covariance, ref[0], 1e-12)
        _close(fast.columns, ref[5], 0)
    if h >= 64:  # the frame has an edge, stripes and noise: the measure is not trivially equal
        assert float(rb[0].min()) > 1e-5 and float(ra[0].max()) < 1e-6
        assert 0 < int(quiet.sum()) < int((~before.isnan()).sum())


@pytest.mark.parametrize(("h", "w"), SIZES)
def test_the_record_of_a_frame_equals_its_first_formulation(h, w):
    before, after = _frames(h, w, seed=3 * h + w)
    after = torch.round(after * 1e3) / 1e3  # as stored in millimetres
    fast, ref = _frame(before, after), dense.frame_record(before, after)

    def flat(d, key=""):
        if isinstance(d, dict):
            return {k2: v2 for k, v in d.items() for k2, v2 in flat(v, f"{key}.{k}").items()}
        return {key: d}

    f, r = flat(fast), flat(ref)
    assert f.keys() == r.keys() | {".change_rms_mm"}
    both = ~(before.isnan() | after.isnan())
    change = (after.double() - before.double())[both]
    rms = 1e3 * float(change.square().mean().sqrt()) if change.numel() else None
    assert f[".change_rms_mm"] == (pytest.approx(rms, rel=1e-12) if rms is not None else None)
    for key in r:
        if r[key] is None:
            assert f[key] is None, key
        else:
            assert f[key] == pytest.approx(r[key], rel=1e-9, abs=1e-9), key
    if h > 100:
        assert r[".stripes.columns.before_mm2"] > 10 * r[".stripes.columns.after_mm2"] > 0


@pytest.mark.parametrize("n", [1, 2, 5, 40])
def test_the_window_sum_is_a_zero_padded_box(n):
    g = torch.Generator().manual_seed(n)
    x = torch.randn(3, n, generator=g, dtype=torch.float64)
    for before, after in ((0, 0), (2, 2), (7, 7), (1, 3), (50, 0)):
        ref = torch.stack([x[:, max(i - before, 0) : i + after + 1].sum(-1) for i in range(n)], -1)
        _close(_window_sum(x, -1, before, after), ref, 1e-12)
        _close(_window_sum(x.T, 0, before, after), ref.T, 1e-12)
        mask = x > 1.0
        counts = torch.stack(
            [mask[:, max(i - before, 0) : i + after + 1].sum(-1) for i in range(n)], -1
        )
        assert torch.equal(_window_sum(mask, -1, before, after), counts.to(torch.int32))


def test_the_dilation_is_a_max_pool():
    g = torch.Generator().manual_seed(0)
    mask = torch.rand(2, 1, 37, 41, generator=g) > 0.995
    for r in (1, 6):
        ref = F.max_pool2d(mask.float(), 2 * r + 1, 1, r) > 0
        assert torch.equal(_dilate(mask, r), ref) and int(ref.sum()) > int(mask.sum()) > 0


@pytest.mark.parametrize(("h", "w"), [(4, 4), (5, 9), (7, 5), (191, 255), (424, 512)])
def test_the_record_noise_equals_estimate_sigma(h, w):
    from tof_fpn_torch.clean.measure import _noise
    from tof_fpn_torch.denoise import estimate_sigma
    from tof_fpn_torch.runtime import valid_mask

    for seed in range(3):
        before, _ = _frames(h, w, seed=seed)
        valid = valid_mask(before)
        x = torch.where(valid, before, 0.0).double()
        ref = float(estimate_sigma(x, valid=valid))
        assert _noise(x, valid) == pytest.approx(ref, rel=1e-12, abs=1e-15)
        if h > 100:
            assert ref == pytest.approx(4e-3, rel=0.1)  # the frames' noise, measured
    none = torch.zeros(1, 1, 8, 8, dtype=torch.bool)
    assert _noise(torch.zeros(1, 1, 8, 8, dtype=torch.float64), none) == 0.0


def test_the_record_of_a_file_measures_its_spread_frames():
    """A 40-frame set: the record is that of its 16 evenly spread frames (the first and the last
    among them), each decoded alone."""
    from tof_fpn_torch.clean.measure import REPORT_FRAMES, file_report
    from tof_fpn_torch.io.stored import FrameSet

    g = torch.Generator().manual_seed(5)
    t, h, w = 40, 48, 64
    depth = 1500 + 30 * torch.arange(t)[:, None, None] + 4 * torch.randn(t, h, w, generator=g)
    depth[:, :, ::2] += 6  # column stripes
    stored = depth.round().clamp(1, 65535).numpy().astype("uint16")
    stored[:, 5, 5] = 0
    out = stored.copy()
    out[:, :, ::2] -= 6
    out[18, :, 1::2] -= 3  # a measured frame changed more than the others
    out[1] -= 20  # a frame changed even more, but not among the measured ones
    fs = FrameSet("", stored, stored.copy(), 1e-3, (t, h, w))
    rec = file_report([fs], {"": out})
    assert rec["measured_frames"] == REPORT_FRAMES
    picks = sorted({round(i * (t - 1) / (REPORT_FRAMES - 1)) for i in range(REPORT_FRAMES)})
    assert picks[0] == 0 and picks[-1] == t - 1
    frames = []
    for i in picks:
        b = torch.from_numpy(stored[i : i + 1, None].astype("float64") * 1e-3).float()
        a = torch.from_numpy(out[i : i + 1, None].astype("float64") * 1e-3).float()
        b[b <= 0], a[a <= 0] = float("nan"), float("nan")
        frames.append(dense.frame_record(b, a))
    for name in ("columns", "rows"):
        for key in ("before_mm2", "after_mm2", "z"):
            ref = sum(f["stripes"][name][key] for f in frames) / len(frames)
            assert rec["stripes"][name][key] == pytest.approx(ref, rel=1e-9, abs=1e-12)
    assert rec["noise_mm"] == pytest.approx(sum(f["noise_mm"] for f in frames) / len(frames))
    assert rec["lowpass_change_mm"] == pytest.approx(max(f["lowpass_change_mm"] for f in frames))
    # the most changed of the measured frames and where it is
    assert 1 not in picks and 18 in picks
    d = out[18].astype(float) - stored[18]
    both = (out[18] > 0) & (stored[18] > 0)
    assert rec["change_frame"] == {"set": "", "frame": 18}
    assert rec["change_rms_mm"] == pytest.approx(math.sqrt((d[both] ** 2).mean()))
    assert rec["stripes"]["columns"]["before_mm2"] > 5 > 10 * rec["stripes"]["columns"]["after_mm2"]


@pytest.mark.parametrize(("h", "w"), SIZES)
def test_a_frame_stored_unchanged_has_the_record_of_its_first_formulation(h, w):
    """``after is before`` (the file_report's shortcut for a frame stored unchanged) gives what
    the full measure of two equal frames gives."""
    before, _ = _frames(h, w, seed=11 * h + w)
    fast, ref = _frame(before, before), dense.frame_record(before, before.clone())
    assert fast.pop("change_rms_mm") == (0.0 if fast["lowpass_change_mm"] is not None else None)
    for name in ("columns", "rows"):
        for key in ("before_mm2", "after_mm2", "z"):
            r = ref["stripes"][name][key]
            f = fast["stripes"][name][key]
            assert f == (None if r is None else pytest.approx(r, rel=1e-9, abs=1e-12))
    for key in ("noise_mm", "lowpass_change_mm", "changed"):
        assert fast[key] == (None if ref[key] is None else pytest.approx(ref[key], abs=1e-12))


def test_the_lower_median_equals_torchs_median_over_the_valid_pixels():
    from tof_fpn_torch.analysis.stripe_energy import _lower_median

    g = torch.Generator().manual_seed(3)
    for n in (1, 2, 7, 10, 1001):
        a = torch.rand(1, 1, 1, n, generator=g)
        v = torch.rand(1, 1, 1, n, generator=g) > 0.3
        v[..., 0] = True
        assert _lower_median(a, v) == float(a[v].median())  # the lower middle value
