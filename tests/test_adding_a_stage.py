"""The worked example of docs/adding-a-stage.md, run as the page shows it: a toy stage registered in
one file appears in the configuration, the CLI, the TOML file, the stage line, the manifest and
the summary, and does what it says to the written files."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from _clean_data import png_folder

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, build_pipeline, config_to_toml, load_config
from tof_fpn_torch.clean.steps import steps, unregister
from tof_fpn_torch.cli import build_parser, main

PAGE = Path(__file__).resolve().parents[1] / "docs" / "adding-a-stage.md"


def _example_code() -> str:
    text = PAGE.read_text()
    m = re.search(r"<!-- adding-a-stage-example -->\s*```python\n(.*?)```", text, re.S)
    assert m, f"no example block in {PAGE}"
    return m.group(1)


@pytest.fixture
def range_step(tmp_path):
    """The page's code as a user has it: one file, imported (which registers the step)."""
    path = tmp_path / "range_step.py"
    path.write_text(_example_code())
    spec = importlib.util.spec_from_file_location("range_step", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    try:
        yield vars(module)
    finally:
        unregister("range")
    assert "range" not in [s.name for s in steps()]


def test_the_example_stage_keeps_the_contract(range_step):
    from stage_tester import check_stage

    check_stage(range_step["DepthRange"](near=0.5, far=1.6))


def test_a_registered_stage_is_in_the_config_the_cli_and_the_toml(range_step, tmp_path):
    names = [s.name for s in steps()]
    assert names.index("range") == names.index("denoise") - 1
    config = CleanConfig(range_far=1.65)
    assert config.range_near == 0.0 and config.range_far == 1.65
    with pytest.raises(ValueError, match="range_far must be a finite number > 0, got -1"):
        CleanConfig(range_far=-1)
    text = config_to_toml(config)
    assert "[range]\nnear = 0.0\nfar = 1.65\n" in text
    path = tmp_path / "c.toml"
    path.write_text(text)
    assert load_config(path) == config
    args = build_parser().parse_args(["clean", "in", "out", "--range-far", "1.7"])
    assert args.range_far == 1.7
    help_text = build_parser()._subparsers._group_actions[0].choices["clean"].format_help()
    assert "--range-near" in help_text and "--range-far" in help_text
    pipe = build_pipeline(CleanConfig(stage="paper", notch="off", range_far=1.65))
    d = torch.tensor([[[[1.0, 1.7], [float("nan"), 1.6]]]])
    y, records = pipe(d, torch.full_like(d, 50.0))
    assert records["range"]["removed"].tolist() == [1.0]
    assert y[0, 0, 0, 1] == 0.0 and y[0, 0, 0, 0] == 1.0 and y[0, 0, 1, 1] == 1.6


def test_a_registered_stage_runs_in_clean_and_is_recorded(range_step, tmp_path, capsys):
    src = png_folder(tmp_path / "in", 3, sub_every=0)
    out = tmp_path / "out"
    far = 1.65
    args = ["clean", str(src), str(out), "--stage", "paper", "--notch", "off"]
    assert main([*args, "--range-far", str(far), "--quiet", "--no-figure"]) == 0
    printed = capsys.readouterr().out
    assert "depth range 0 to 1.65 m" in printed
    assert "[range]" in (out / "clean.toml").read_text()
    lines = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    start = next(x for x in lines if "pipeline" in x)
    assert start["pipeline"]["range"] == [0.0, far]
    removed_total = 0
    for rec in (x for x in lines if x.get("status") == "done"):
        name = rec["file"]
        d_in = tio.read_png(src / name, allow_empty=True)[0, 0].numpy()
        d_out = tio.read_png(out / name, allow_empty=True)[0, 0].numpy()
        outside = np.isfinite(d_in) & (d_in > far)
        assert outside.sum() > 0  # the example removes something: the test can fail
        assert rec["report"]["range"] == {"removed": int(outside.sum())}
        assert np.isnan(d_out[outside]).all()
        keep = np.isfinite(d_in) & ~outside
        assert np.array_equal(d_out[keep], d_in[keep])
        removed_total += int(outside.sum())
    assert f"depth range: {removed_total} pixel(s) removed" in printed
