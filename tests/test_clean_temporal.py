"""``tof-fpn clean --temporal``: the filter over the frames of a recording in order (equal to the
module run by hand with the recorded noise), not applied to single-frame files (said and
recorded), off by default, and its settings in the configuration."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch
from _clean_data import png_folder, tree

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig
from tof_fpn_torch.clean.config import config_from_dict
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.cli import main
from tof_fpn_torch.runtime import TemporalFilter

IDENTITY = ["--notch", "off", "--destripe", "off", "--quiet", "--no-figure"]


def _recording(path, t=12, h=24, w=32):
    """A wall at 2 m with noise k / A and a board that jumps in at frame 6; a few holes."""
    g = torch.Generator().manual_seed(0)
    amp = 50.0 + 100.0 * torch.rand(1, 1, h, w, generator=g).expand(t, 1, h, w)
    depth = 2.0 + (0.5 / amp) * torch.randn(t, 1, h, w, generator=g)
    depth[6:, :, 5:15, 8:20] -= 0.7
    depth[3:5, :, 0, 0] = float("nan")
    meta = {"modulation_frequency_hz": 20e6, "integration_time_us": None, "n_phases": 4}
    tio.write_recording(path, tio.Recording(depth, amp.contiguous(), meta))
    return depth, amp.contiguous()


def _records(out):
    return [r for r in read_manifest(os.path.join(out, "manifest.jsonl")) if "file" in r]


def test_a_recording_is_filtered_in_time_order(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    depth, amp = _recording(src / "rec.npz")
    out = tmp_path / "out"
    assert main(["clean", str(src), str(out), "--temporal", *IDENTITY]) == 0
    stdout = capsys.readouterr().out
    assert "temporal (alpha 0.2, guard 3, persistence 0)" in stdout
    assert "temporal: applied to 1 frame set(s) (12 frames)" in stdout
    (rec,) = _records(out)
    (info,) = rec["temporal"]
    assert info["applied"] and info["frames"] == 12 and info["noise_k"] > 0
    assert info["restarts"] >= 120  # the board's 10 x 12 pixels restart when it jumps in
    f = TemporalFilter(0.2, 3.0, info["sigma_m"], info["noise_k"])
    state, ref = f.initial_state(depth[:1]), []
    for i in range(depth.shape[0]):
        y, state = f(depth[i : i + 1], state, amp[i : i + 1])
        ref.append(y)
    got = tio.read_recording(out / "rec.npz").depth
    torch.testing.assert_close(got, torch.cat(ref), rtol=0, atol=1e-6, equal_nan=True)
    still = (got[6:, 0, 5:15, 8:20] - (1.3 + 0.0)).abs()
    assert float(still.max()) < 0.05  # no trail behind the jump
    assert "temporal = true" in (out / "clean.toml").read_text()


def test_single_frame_files_are_not_filtered_and_it_says_so(tmp_path, capsys):
    src = png_folder(tmp_path / "in", 4, sub_every=0)
    plain, temporal = tmp_path / "plain", tmp_path / "temporal"
    assert main(["clean", str(src), str(plain), *IDENTITY]) == 0
    capsys.readouterr()
    assert main(["clean", str(src), str(temporal), "--temporal", *IDENTITY]) == 0
    stdout = capsys.readouterr().out
    assert "temporal: NOT applied to 4 frame set(s) (one frame: no time order)" in stdout
    for rec in _records(temporal):
        assert rec["temporal"] == [
            {"applied": False, "frames": 1, "reason": "one frame: no time order"}
        ]
    skip = ("manifest.jsonl", "clean.toml", "report.png")
    assert tree(plain, skip) == tree(temporal, skip)  # the same bytes: nothing was done


def test_off_by_default_and_recorded(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    depth, _ = _recording(src / "rec.npz")
    out = tmp_path / "out"
    assert main(["clean", str(src), str(out), *IDENTITY]) == 0
    assert "temporal" not in capsys.readouterr().out
    (rec,) = _records(out)
    assert "temporal" not in rec
    assert "temporal = false" in (out / "clean.toml").read_text()
    got = tio.read_recording(out / "rec.npz").depth
    torch.testing.assert_close(got, depth, rtol=0, atol=0, equal_nan=True)  # untouched


def test_settings_from_the_configuration():
    c = config_from_dict({"pipeline": {"temporal": True}, "temporal": {"alpha": 0.5, "guard": 4}})
    assert c.temporal and c.temporal_alpha == 0.5 and c.temporal_guard == 4.0
    assert CleanConfig().temporal is False
    with pytest.raises(ValueError, match="alpha"):
        config_from_dict({"temporal": {"alpha": 1.5}})
    with pytest.raises(ValueError, match="temporal_persistence"):
        config_from_dict({"temporal": {"persistence": -1}})
    with pytest.raises(ValueError, match="temporal must be true or false"):
        config_from_dict({"pipeline": {"temporal": "yes"}})
    assert np.isfinite(c.temporal_alpha)
