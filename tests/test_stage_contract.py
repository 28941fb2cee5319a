"""Every run-time stage of the package passes the one stage tester (``tests/stage_tester.py``), and
the contract's declarations (:mod:`tof_fpn_torch.runtime.stage`) check what they say."""

from __future__ import annotations

import math

import pytest
import torch
from stage_tester import check_stage, scene

from tof_fpn_torch import denoise
from tof_fpn_torch.build import suppression_from_design
from tof_fpn_torch.runtime import (
    ComplexPatternCorrection,
    Destripe,
    FixedPatternCorrection,
    FlyingPixels,
    FPNSuppression,
    PatternCorrection,
    TemporalSequence,
)
from tof_fpn_torch.runtime.stage import RecordOutputs, Setting, Stage, check_settings

H, W = 36, 44

STAGES = {
    "suppression (paper, gated)": lambda: suppression_from_design(20, 0.14),
    "suppression (ungated, destripe)": lambda: suppression_from_design(
        20, 0.14, gate=False, destripe=Destripe()
    ),
    "suppression (destripe only)": lambda: FPNSuppression(None, None, destripe=Destripe(dim=-2)),
    "destripe (depth)": lambda: Destripe(dim=(-2, -1)),
    "destripe (complex)": lambda: Destripe(domain="complex", modulation_frequency_hz=20e6),
    "fixed pattern": lambda: FixedPatternCorrection(
        0.002 * torch.cos(math.pi * torch.arange(W)), row_offset=0.001 * torch.ones(H)
    ),
    "complex pattern": lambda: ComplexPatternCorrection(
        torch.full((W,), 0.5), torch.full((W,), -0.3), modulation_frequency_hz=20e6
    ),
    "pattern (offsets)": lambda: PatternCorrection(
        [FixedPatternCorrection(0.002 * torch.cos(math.pi * torch.arange(W)), height=H)]
    ),
    "pattern (offsets, read-out)": lambda: PatternCorrection(
        [
            FixedPatternCorrection(0.002 * torch.cos(math.pi * torch.arange(W)), height=H),
            ComplexPatternCorrection(
                torch.full((W,), 0.5), torch.full((W,), -0.3), modulation_frequency_hz=20e6
            ),
        ],
        learned='{"frames": 6}',
    ),
    "temporal": lambda: TemporalSequence(sigma=0.002, noise_k=0.5, persistence=2),
    **{f"flying ({a})": (lambda a=a: FlyingPixels(a)) for a in ("mark", "invalidate", "reassign")},
}


@pytest.mark.parametrize("name", sorted(STAGES))
def test_every_stage_keeps_the_contract(name):
    check_stage(STAGES[name]())


@pytest.mark.parametrize("name", denoise.names())
def test_every_denoiser_keeps_the_contract(name):
    # the joint bilateral is guided by the amplitude; the others use it for their noise law
    check_stage(denoise.get(name), scriptable=denoise.scriptable(name))


def test_the_gate_is_recorded_from_the_one_pass():
    """The record's gate is the one the frame was made with: closed (0) on a stripe-free frame,
    which comes out unchanged, open on a striped one, 1 without the gate, NaN without a notch."""
    stage = suppression_from_design(20, 0.14)
    g = torch.Generator().manual_seed(3)
    x = torch.arange(W, dtype=torch.float32)
    stripes = 0.01 * torch.cos(math.pi * x) + 0.006 * torch.cos(2 * math.pi / 3 * x)
    flat = 2.0 + 0.002 * torch.randn(2, 1, H, W, generator=g)
    striped = flat + stripes
    amp = torch.full_like(flat, 100.0)
    with torch.no_grad():
        y, rec = stage.run(torch.cat([striped[:1], flat[1:]]), amp)
    assert rec["gate"][0] > 0.5 and rec["gate"][1] == 0.0
    assert torch.equal(y[1], flat[1]) and not torch.equal(y[0], striped[0])
    ungated = suppression_from_design(20, 0.14, gate=False)
    assert ungated.run(flat, amp)[1]["gate"].tolist() == [1.0, 1.0]
    no_notch = FPNSuppression(None, None, destripe=Destripe()).run(flat, amp)[1]["gate"]
    assert torch.isnan(no_notch).all()


def test_settings_check_what_they_declare():
    s = Setting("width", int, 5, "columns", low=3)
    assert s.check(3) == 3
    for bad in (2, 3.0, True, "4"):
        with pytest.raises(ValueError, match=r"width must be an int >= 3, got"):
            s.check(bad)
    f = Setting("clip", float, 1.0, "sigmas", low=0.0, open_low=True, high=5.0)
    assert f.check(2) == 2.0 and isinstance(f.check(2), float)
    for bad in (0.0, 5.5, math.nan, math.inf):
        with pytest.raises(ValueError, match=r"clip must be a finite number > 0 and <= 5"):
            f.check(bad)
    assert Setting("guard", float, 3.0, "sd", finite=False).check(math.inf) == math.inf
    c = Setting("mode", str, "a", "mode", choices=("a", "b"))
    with pytest.raises(ValueError, match=r"mode must be one of \['a', 'b'\], got 'c'"):
        c.check("c")
    with pytest.raises(ValueError, match="kind must be one of"):
        Setting("x", list, None, "no")
    with pytest.raises(ValueError, match=r"width must be an int >= 3, got 1"):
        Setting("width", int, 1, "bad default", low=3)
    with pytest.raises(ValueError, match=r"Destripe has no setting 'bogus'; its settings: \["):
        check_settings(Destripe, bogus=1)
    with pytest.raises(ValueError, match="clip must be"):
        Destripe(clip=-1.0)


def test_a_stage_runs_in_float32_under_autocast():
    stage = FlyingPixels("reassign")
    depth, amp = scene(b=1)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        y, rec = stage.run(depth, amp)
    assert y.dtype == torch.float32
    torch.testing.assert_close(y, stage(depth, amp), equal_nan=True)


def test_record_outputs_export_declared_fields_only():
    depth, amp = scene(b=1)
    m = RecordOutputs(FlyingPixels("mark"), ("confidence",))
    y, conf = m(depth, amp)
    ref, rec = FlyingPixels("mark").run(depth, amp)
    assert torch.equal(conf, rec["confidence"]) and m.onnx_outputs == ["output", "confidence"]
    with pytest.raises(ValueError, match="records .*'flagged'.*not 'gate'"):
        RecordOutputs(FlyingPixels("mark"), ("gate",))


def test_a_stage_without_run_says_so():
    class Empty(Stage):
        pass

    with pytest.raises(NotImplementedError, match="_run"):
        Empty()(torch.ones(1, 1, 2, 2))
