"""``tof-fpn clean`` configuration (TOML, flags) and the pipeline it builds, stage by stage."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from tof_fpn_torch import cameras
from tof_fpn_torch import constants as K
from tof_fpn_torch.clean import (
    DENOISERS,
    Calibration,
    CleanConfig,
    build_pipeline,
    config_from_dict,
    config_to_toml,
    describe,
    load_config,
    register_denoiser,
)
from tof_fpn_torch.clean.config import BATCH
from tof_fpn_torch.cli import build_parser
from tof_fpn_torch.cli.clean import config_from_args
from tof_fpn_torch.denoise import NonLocalMeans
from tof_fpn_torch.runtime import Destripe


def _frames(b=4, h=40, w=64, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.arange(w)
    stripes = 0.01 * torch.cos(math.pi * x) + 0.004 * torch.randn(w, generator=g)
    depth = 2.0 + stripes + 0.002 * torch.randn(b, 1, h, w, generator=g)
    amp = 50 + 300 * torch.rand(b, 1, h, w, generator=g)
    return depth, amp


def test_toml_round_trip_and_version(tmp_path):
    cfg = CleanConfig(
        destripe="both", notch="design", fusion="manual", low=10.0, high=60.0, rho=0.2,
        denoise="nlm", denoise_options={"h": 0.9, "kernel": "box"}, batch=3, height=4, width=5,
    )  # fmt: skip
    text = config_to_toml(cfg)
    assert text.startswith('[tof_fpn_torch]\nversion = "')
    p = tmp_path / "c.toml"
    p.write_text(text)
    assert load_config(p) == cfg
    assert load_config(p).identity() == cfg.identity()


def test_defaults_are_the_package_defaults():
    cfg = CleanConfig()
    assert cfg.stage == "auto" and cfg.rounding == "dither" and cfg.camera is None
    assert (cfg.notch, cfg.fusion, cfg.destripe, cfg.denoise) == ("data", "data", "auto", "none")
    assert cfg.order == K.DEFAULT_ORDER and cfg.batch == BATCH
    assert CleanConfig(notch="off").fusion == "off"
    paper = CleanConfig(stage="paper")
    assert (paper.notch, paper.fusion, paper.destripe, paper.camera) == (
        "design",
        "camera",
        "off",
        "camcube",
    )
    # an explicit key wins over the preset; a new preset brings its own defaults
    assert CleanConfig(stage="paper", destripe="columns").destripe == "columns"
    assert cfg.replace(stage="paper").notch == "design"
    assert paper.replace(stage="auto").camera is None
    assert cfg.replace(notch="design").fusion == "camera"  # the fusion that goes with it
    with pytest.raises(ValueError, match="unknown camera profile 'kinekt'"):
        CleanConfig(camera="kinekt")


@pytest.mark.parametrize(
    "data, needle",
    [
        ({"pipeline": {"notch": "fir"}}, "notch must be one of"),
        ({"pipeline": {"colour": "x"}}, "unknown key 'colour' in \\[pipeline\\]"),
        ({"extras": {}}, "unknown table 'extras'"),
        ({"pipeline": {"notch": "off", "fusion": "camera"}}, "needs notch"),
        ({"pipeline": {"fusion": "manual"}}, "needs low and high"),
        ({"files": {"batch": 0}}, "batch must be an int >= 1"),
        ({"notch": {"rho": -1.0}}, "rho must be a finite number > 0, got -1.0"),
        ({"notch": {"gate": "yes"}}, "gate must be true or false"),
        ({"pipeline": {"stage": "best"}}, "stage must be one of \\['auto', 'paper'\\]"),
        ({"files": {"rounding": "up"}}, "rounding must be one of"),
        ({"files": {"output_scale": 0}}, "output_scale must be a finite number > 0, got 0"),
    ],
)
def test_bad_config_names_key_value_allowed(data, needle):
    with pytest.raises(ValueError, match=needle):
        config_from_dict(data)


def test_invalid_toml_is_one_clear_error(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[pipeline\n")
    with pytest.raises(ValueError, match="not valid TOML"):
        load_config(p)


def test_flags_override_the_file(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text('[pipeline]\ndenoise = "nlm"\n[denoise]\nh = 0.5\n[notch]\norder = 30\n')
    args = build_parser().parse_args(
        ["clean", "in", "out", "--config", str(p), "--order", "12", "--denoise-opt", "patch_size=5"]
    )
    cfg = config_from_args(args)
    assert cfg.order == 12 and cfg.denoise == "nlm"
    assert cfg.denoise_options == {"h": 0.5, "patch_size": 5}
    args = build_parser().parse_args(["clean", "in", "out", "--notch", "off"])
    assert config_from_args(args).fusion == "off"


def test_each_stage_subset_builds_what_it_says():
    d, a = _frames()
    empty = build_pipeline(CleanConfig(stage="paper", notch="off"))
    assert (
        empty.stage("fpn") is None
        and empty.stage("denoise") is None
        and torch.equal(empty(d, a)[0], d)
    )
    only = build_pipeline(CleanConfig(notch="off", destripe="columns"))
    assert only.stage("fpn").filter is None and isinstance(only.stage("fpn").destripe, Destripe)
    full = build_pipeline(CleanConfig(stage="paper", destripe="rows", denoise="nlm"))
    info = describe(full)
    assert info["notch"]["order"] == K.DEFAULT_ORDER and info["fusion"]["low"] == K.FUSION_LOW
    assert isinstance(full.stage("denoise"), NonLocalMeans) and info["destripe"].startswith(
        "dim=(-2,)"
    )
    no_fusion = build_pipeline(CleanConfig(stage="paper", fusion="off", gate=False))
    assert no_fusion.stage("fpn").fusion is None and no_fusion.stage("fpn").gate is False


def test_data_stages_are_measured_on_the_calibration_frames():
    d, a = _frames()
    calls = []

    def calib():
        calls.append(1)
        return Calibration(d, a)

    p = build_pipeline(CleanConfig(), calib)  # the default: every piece measured
    assert len(calls) == 1  # read once per build
    assert any(abs(w - math.pi) < 0.05 for w in p.stage("fpn").filter.notches)
    assert p.stage("fpn").fusion is not None and p.stage("fpn").fusion.low != K.FUSION_LOW
    g = torch.Generator().manual_seed(1)
    offsets = (
        2.0 + 0.004 * torch.randn(64, generator=g) + 0.002 * torch.randn(4, 1, 40, 64, generator=g)
    )
    for notch in ("off", "design"):  # random column offsets: broadband
        auto = build_pipeline(
            CleanConfig(notch=notch, destripe="auto"), lambda: Calibration(offsets, a)
        )
        assert isinstance(auto.stage("fpn").destripe, Destripe), notch
    flat = build_pipeline(CleanConfig(), lambda: Calibration(d * 0 + 2.0, a))
    assert flat.stage("fpn") is None  # nothing to remove: no stage
    with pytest.raises(ValueError, match="no calibration frames"):
        build_pipeline(CleanConfig(stage="paper", fusion="data"))
    # fusion = camera: the files' camera profile, unless one is configured
    adi = build_pipeline(
        CleanConfig(notch="design", destripe="off"), lambda: Calibration(d, a, "adtf3175")
    )
    assert adi.stage("fpn").fusion.low == cameras.profile("adtf3175").fusion_low
    cc = build_pipeline(CleanConfig(stage="paper"), lambda: Calibration(d, a, "adtf3175"))
    assert cc.stage("fpn").fusion.low == K.FUSION_LOW


def test_denoiser_registry_takes_new_names():
    class Halve(nn.Module):
        def __init__(self, factor: float = 0.5):
            super().__init__()
            self.factor = factor

        def forward(self, depth, amplitude):
            return depth * self.factor

    register_denoiser("halve", Halve)
    try:
        p = build_pipeline(
            CleanConfig(
                stage="paper", notch="off", denoise="halve", denoise_options={"factor": 2.0}
            )
        )
        assert torch.equal(
            p(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 2, 2))[0], torch.full((1, 1, 2, 2), 2.0)
        )
        with pytest.raises(ValueError, match="unknown option.*'size'.*allowed.*factor"):
            build_pipeline(
                CleanConfig(
                    stage="paper", notch="off", denoise="halve", denoise_options={"size": 1}
                )
            )
    finally:
        DENOISERS.pop("halve")
    with pytest.raises(ValueError, match="denoise must be 'none' or one of"):
        build_pipeline(CleanConfig(stage="paper", denoise="wiener"))
    with pytest.raises(ValueError, match="identifier"):
        register_denoiser("none", Halve)


def test_the_auto_stage_falls_back_when_the_design_refuses_its_notch(monkeypatch):
    """A measured notch whose filter the design refuses (e.g. 3.113 rad on a 171 x 229 frame:
    rho 0.008) is dropped, the rest is measured, and the stage line says why; with a rho the
    user chose, the refusal is theirs to see."""
    from tof_fpn_torch.build import DesignRefused
    from tof_fpn_torch.clean.pipeline import stage_line
    from tof_fpn_torch.clean.steps import fpn as fpn_step

    def refuse(*args, **kwargs):
        raise DesignRefused(
            "the design {order 20, rho 0.0082} for notches [3.113] has a passband ripple of "
            "-0.0 dB (DC gain 1.000); the stage needs <= -20 dB: use a higher order or a larger rho"
        )

    monkeypatch.setattr(fpn_step, "suppression_from_data", refuse)
    g = torch.Generator().manual_seed(1)
    offsets = (
        2.0 + 0.004 * torch.randn(64, generator=g) + 0.002 * torch.randn(4, 1, 40, 64, generator=g)
    )
    a = torch.full_like(offsets, 100.0)
    p = build_pipeline(CleanConfig(), lambda: Calibration(offsets, a))
    assert p.stage("fpn").filter is None and isinstance(p.stage("fpn").destripe, Destripe)
    line = stage_line(describe(p), "auto")
    assert "the notch fell back to none: the design {order 20, rho 0.0082}" in line
    assert "use a higher order" not in line and "destripe" in line
    with pytest.raises(DesignRefused, match="passband ripple"):
        build_pipeline(CleanConfig(rho=0.01), lambda: Calibration(offsets, a))
