"""Every run-time stage on real ToF captures (ADI ADTF3175, ``tests/data/real``).

Inputs: the wall frame (depth mm + IR as amplitude) and the office frame (depth mm + active
brightness as amplitude, 6 % invalid) as one large batch of two 512 x 512 frames, and crops of
odd (111 x 77, 133 x 91) and tiny size (1 x 1, 1 x 9, 7 x 1, 3 x 2) placed over invalid pixels and
the wall's 3.6 m spike. Invalid = depth 0 (the camera's code; the amplitudes are all valid). For
every stage and input:

* invalid pixels come out bit-identical;
* valid pixels stay finite, and nothing valid becomes invalid (<= 0);
* the change at valid pixels is bounded by what the stage can do (each bound is derived where it
  is checked, from the stage's definition, not from its output).

There is no ground truth, so no PSNR against one; the metrics are checked against NumPy on the
same data instead.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.ndimage import maximum_filter, minimum_filter

from tof_fpn_torch import estimate_stripes
from tof_fpn_torch import metrics as M
from tof_fpn_torch.build import filter_from_design, suppression_from_design
from tof_fpn_torch.denoise import non_local_means
from tof_fpn_torch.runtime import amplitude_fusion, amplitude_weight, valid_mask

NLM = dict(patch_size=5, patch_distance=3)
STAGES = ("filter", "suppression", "nlm", "fusion")
FRAMES = "wall+office"  # batch index 0: wall, 1: office
EPS32 = float(torch.finfo(torch.float32).eps)


@pytest.fixture(scope="module")
def inputs(real_data) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """name -> (depth, amplitude), float32 (B, 1, H, W), contiguous."""
    wd, wa = real_data.adi_wall()
    od, _, oa = real_data.adi_office()

    def crop(d, a, rows, cols):
        return d[..., rows, cols].contiguous(), a[..., rows, cols].contiguous()

    out = {
        FRAMES: (torch.cat([wd, od]), torch.cat([wa, oa])),
        "wall_111x77": crop(wd, wa, slice(401, 512), slice(0, 77)),
        "office_133x91": crop(od, oa, slice(101, 234), slice(57, 148)),
        "office_1x1": crop(od, oa, slice(33, 34), slice(419, 420)),
        "office_1x9": crop(od, oa, slice(33, 34), slice(415, 424)),
        "office_7x1": crop(od, oa, slice(30, 37), slice(419, 420)),
        "office_3x2": crop(od, oa, slice(32, 35), slice(418, 420)),
    }
    # the crops hold what they are meant to: invalid pixels, and the wall's spike
    for name in ("wall_111x77", "office_133x91", "office_1x1", "office_1x9", "office_3x2"):
        assert bool((out[name][0] == 0).any()), name
    assert float(out["wall_111x77"][0].max()) > 3000.0
    return out


@pytest.fixture(scope="module")
def fpn():
    return filter_from_design()  # Table I's {20, 0.14}, along the width


@pytest.fixture(scope="module")
def stage():
    # ungated: eq. (11) is checked exactly below; the gate (test_suppression.py) would leave
    # these stripe-free frames as they are
    return suppression_from_design(gate=False)


@pytest.fixture(scope="module")
def runs(inputs, fpn, stage):
    """``(outputs, errors)``: name -> {stage: output} for every stage that ran, and
    (name, stage) -> the error of every one that raised. ``test_every_stage_runs_on_every_input``
    fails on the errors; the other tests check the outputs there are (always the full frames)."""
    outputs, errors = {}, {}
    for name, (d, a) in inputs.items():
        out = outputs.setdefault(name, {})
        calls = {
            "filter": lambda d=d: fpn(d),
            "suppression": lambda d=d, a=a: stage(d, a),
            "nlm": lambda d=d, a=a: non_local_means(d, a, **NLM),
            "fusion": lambda d=d, a=a, out=out: amplitude_fusion(out["nlm"], d, a),
        }
        for stage_name, call in calls.items():
            if stage_name == "fusion" and "nlm" not in out:
                errors[(name, stage_name)] = "not run: it fuses the NLM output"
                continue
            try:
                with torch.inference_mode():
                    out[stage_name] = call()
            except Exception as exc:  # noqa: BLE001 -- recorded, failed on below
                errors[(name, stage_name)] = f"{type(exc).__name__}: {exc}"
    assert set(outputs[FRAMES]) == set(STAGES), errors
    return outputs, errors


@pytest.fixture(scope="module")
def outputs(runs):
    return runs[0]


def _ran(outputs, stage_name):
    """``(name, output)`` for the inputs the stage ran on."""
    return [(name, out[stage_name]) for name, out in outputs.items() if stage_name in out]


def _bits(x: torch.Tensor) -> torch.Tensor:
    return x.contiguous().view(torch.int32)


def test_every_stage_runs_on_every_input(inputs, runs):
    """Every stage takes every input, the 1-pixel and 3 x 2 crops too."""
    outputs, errors = runs
    assert not errors, errors
    assert all(set(outputs[name]) == set(STAGES) for name in inputs)


@pytest.mark.parametrize("stage_name", STAGES)
def test_invalid_pixels_bit_identical_and_valid_pixels_finite(inputs, outputs, stage_name):
    for name, out in _ran(outputs, stage_name):
        d, a = inputs[name]
        assert out.shape == d.shape and out.dtype == d.dtype, name
        valid = valid_mask(d, a)
        assert torch.equal(_bits(out)[~valid], _bits(d)[~valid]), (name, stage_name)
        assert bool(torch.isfinite(out[valid]).all()), (name, stage_name)


@pytest.mark.parametrize("stage_name", STAGES)
def test_no_valid_pixel_becomes_invalid(inputs, outputs, stage_name):
    """A valid measurement must not come out as a "no measurement" code (<= 0)."""
    bad = {}
    for name, out in _ran(outputs, stage_name):
        d, a = inputs[name]
        now_invalid = valid_mask(d, a) & ~valid_mask(out)
        if bool(now_invalid.any()):
            where = torch.nonzero(now_invalid)[:3].tolist()
            bad[name] = (int(now_invalid.sum()), where, out[now_invalid][:3].tolist())
    assert not bad, (
        f"{stage_name}: valid pixels turned invalid (count, [b, c, y, x], values): {bad}"
    )


def test_filter_output_within_the_interval_its_taps_allow(inputs, outputs, fpn):
    """FPNFilter along the width: every input sample of the FIR at a valid pixel is a valid depth
    of the same row, or a hole filled with a convex combination of them (normalized convolution
    or the row mean; reflect borders stay in the row). So with ``lo``/``hi`` the row's valid
    range and ``P``/``N`` the sums of the positive / absolute negative taps, the output lies in
    ``[P lo - N hi, P hi - N lo]`` (interval arithmetic), up to float32 rounding."""
    taps = fpn.taps.double()
    pos, neg = float(taps.clamp_min(0).sum()), float((-taps).clamp_min(0).sum())
    for name, out in _ran(outputs, "filter"):
        d = inputs[name][0]
        valid = valid_mask(d)
        lo = torch.where(valid, d, torch.full_like(d, math.inf)).amin(-1, keepdim=True).double()
        hi = torch.where(valid, d, torch.full_like(d, -math.inf)).amax(-1, keepdim=True).double()
        tol = 8 * EPS32 * (pos + neg) * hi.abs()
        low, high = pos * lo - neg * hi - tol, pos * hi - neg * lo + tol
        out = out.double()
        assert bool(((out >= low) & (out <= high))[valid].all()), name
    # the bound is not vacuous: on the wall the filter does move pixels by millimetres
    d, wall = inputs[FRAMES][0][:1], outputs[FRAMES]["filter"][:1]
    change = (wall - d)[valid_mask(d)].abs()
    assert float((change > 0.5).double().mean()) > 0.02


def test_suppression_and_fusion_move_each_pixel_by_delta_towards_the_filtered_depth(
    inputs, outputs, fpn, stage
):
    """Eq. (11): ``out = D + delta(A) (D_F - D)`` with ``delta`` in [0.2, 1], so at a valid pixel
    ``|out - D| = delta(A) |D_F - D|`` and ``out`` lies between ``D`` and ``D_F``. ``D_F`` is the
    stage's own filter with the stage's validity (depth and amplitude) for the suppression, and
    the NLM output for the fusion."""
    assert torch.equal(stage.filter.taps, fpn.taps)
    for name, (d, a) in inputs.items():
        valid = valid_mask(d, a)
        delta = amplitude_weight(a).double()
        assert bool(((delta >= 0.2) & (delta <= 1.0)).all())
        with torch.inference_mode():
            targets = {"suppression": stage.filter(d, valid), "fusion": outputs[name].get("nlm")}
        for key, target in targets.items():
            if key not in outputs[name] or not bool(valid.any()):
                continue  # did not run (test_every_stage_runs_on_every_input fails), or no pixel
            out, dd, t = outputs[name][key].double(), d.double(), target.double()
            tol = 4 * EPS32 * torch.maximum(dd.abs(), t.abs())
            lo, hi = torch.minimum(dd, t) - tol, torch.maximum(dd, t) + tol
            assert bool(((out >= lo) & (out <= hi))[valid].all()), (name, key)
            err = ((out - dd).abs() - delta * (t - dd).abs())[valid].abs()
            assert bool((err <= tol[valid]).all()), (name, key, float(err.max()))


def _window_hull(d: np.ndarray, valid: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Min / max of the valid values in the ``(2 radius + 1)^2`` window around every pixel of
    the reflect-padded image (NumPy ``reflect``, repeated for tiny images)."""
    lo = np.pad(np.where(valid, d, np.inf), radius, mode="reflect")
    hi = np.pad(np.where(valid, d, -np.inf), radius, mode="reflect")
    size = 2 * radius + 1
    inner = (slice(radius, radius + d.shape[0]), slice(radius, radius + d.shape[1]))
    return minimum_filter(lo, size)[inner], maximum_filter(hi, size)[inner]


def test_nlm_output_within_its_search_window(inputs, outputs):
    """NLM returns a weighted mean, with weights >= 0 and the pixel's own weight 1, of the valid
    pixels in its (2d + 1)^2 search window (reflected at the borders): every valid output lies
    between the smallest and largest valid depth of that window."""
    r = NLM["patch_distance"]
    for name, out in _ran(outputs, "nlm"):
        d, a = inputs[name]
        valid = valid_mask(d, a)
        for b in range(d.shape[0]):
            x, v, o = d[b, 0].numpy(), valid[b, 0].numpy(), out[b, 0].numpy()
            lo, hi = _window_hull(x, v, r)
            tol = 8 * EPS32 * np.abs(x).max()
            assert np.all((o >= lo - tol)[v]) and np.all((o <= hi + tol)[v]), (name, b)
    # the bound is not vacuous: NLM smooths the wall's noise (millimetres)
    d, a = (t[:1] for t in inputs[FRAMES])
    change = (outputs[FRAMES]["nlm"][:1] - d)[valid_mask(d, a)].abs()
    assert float(change.mean()) > 0.1


def test_batch_equals_each_frame_for_the_filter_stages(inputs, outputs, fpn, stage):
    """The two frames as one batch give each frame's own result (the filter runs the flattened
    batch as one signal; NLM's batch independence is in test_nlm.py)."""
    d, a = inputs[FRAMES]
    with torch.inference_mode():
        for i in range(2):
            di, ai = d[i : i + 1], a[i : i + 1]
            torch.testing.assert_close(outputs[FRAMES]["filter"][i : i + 1], fpn(di))
            torch.testing.assert_close(outputs[FRAMES]["suppression"][i : i + 1], stage(di, ai))


def test_stripe_estimate_on_real_frames(inputs):
    """The wall's column offsets are broadband (README of the data: no peak at 2pi/3 or pi in
    the column profile): no column stripe is reported there. On every input the components are
    well-formed, and what invalid pixels hold (0 or NaN) does not change the estimate."""
    d, a = inputs[FRAMES]
    cases = {"wall": (d[:1], a[:1]), "office": (d[1:], a[1:])}
    cases.update({k: v for k, v in inputs.items() if k != FRAMES and min(v[0].shape[-2:]) >= 8})
    for name, (d, a) in cases.items():
        est = estimate_stripes(d, a)
        comps = list(est.components)
        if name == "wall":  # without amplitude weights too
            comps += estimate_stripes(d).components
            near = [
                c
                for c in comps
                if c.orientation == "columns"
                and min(abs(c.frequency - w) for w in (2 * math.pi / 3, math.pi)) < 0.05
            ]
            assert not near, near
        for c in comps:
            assert 0.15 * math.pi <= c.frequency <= math.pi, (name, c)
            assert c.dim == (-1 if c.orientation == "columns" else -2)
            assert math.isfinite(c.strength) and c.strength >= 0
            assert c.snr_db >= 10.0  # the default threshold
            assert c.confidence == pytest.approx(1 - 10 ** (-c.snr_db / 10), abs=1e-9)
        holes_nan = torch.where(d > 0, d, torch.full_like(d, math.nan))
        assert estimate_stripes(holes_nan, a).components == est.components, name


def _median3x3_valid(x: np.ndarray) -> np.ndarray:
    """3 x 3 median of the valid (> 0, finite) neighbours, edge-replicated (NumPy reference)."""
    xv = np.where(np.isfinite(x) & (x > 0), x, np.nan)
    p = np.pad(xv, 1, mode="edge")
    h, w = x.shape
    stack = np.stack([p[i : i + h, j : j + w] for i in range(3) for j in range(3)])
    with np.errstate(all="ignore"):
        return np.nanmedian(stack, axis=0)


def test_metrics_on_real_frames(inputs, outputs):
    """IMP / LOW shares and the error of each stage's output against its input, against NumPy."""
    d, a = inputs[FRAMES]
    corner = d[:1, :, 448:, :128].double() / 1000.0  # metres; the wall's holes and spike
    imp = M.impulsive_mask(corner)
    x = corner[0, 0].numpy()
    with np.errstate(invalid="ignore"):
        ref = ~(x > 0) | (np.abs(x - _median3x3_valid(x)) > 0.5)
    np.testing.assert_array_equal(imp[0, 0].numpy(), ref)
    assert int(imp.sum()) == 4  # the three holes and the 3.6 m spike
    assert bool(imp[0, 0, 511 - 448, 52]) and float(d[0, 0, 511, 52]) > 3000.0
    low = M.low_sensing_fraction(a)  # IR counts, not CamCube units: the computation is checked
    np.testing.assert_allclose(low.numpy(), (a.numpy() < 300).reshape(2, -1).mean(1), rtol=1e-6)
    for name, (d, a) in inputs.items():
        valid = valid_mask(d, a)
        for stage_name, out in outputs[name].items():
            out = out.double()
            for b in range(d.shape[0]):
                o, t, v = out[b : b + 1], d[b : b + 1].double(), valid[b : b + 1]
                err = (o - t)[v].numpy()
                if err.size == 0:  # nothing to evaluate: the metrics refuse
                    with pytest.raises(ValueError, match="no valid pixel"):
                        M.rmse(o, t, v)
                    continue
                rms = np.sqrt(np.mean(err**2))
                np.testing.assert_allclose(float(M.rmse(o, t, v)), rms, rtol=1e-9, atol=1e-12)
                np.testing.assert_allclose(
                    float(M.mae(o, t, v)), np.mean(np.abs(err)), rtol=1e-9, atol=1e-12
                )
                if rms > 0:  # eq. (9) with the peak in mm
                    want = 20 * np.log10(7500.0 / rms)
                    got = float(M.psnr(o, t, v, d_max=7500.0))
                    assert got == pytest.approx(want, abs=1e-9), (name, stage_name)
