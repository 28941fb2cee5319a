"""``tof-fpn calibrate`` (a fixed pattern from wall recordings) and ``tof-fpn clean --pattern``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from tof_fpn_torch.clean.pattern import read_pattern
from tof_fpn_torch.cli import main


def _pair(folder, name, depth_mm, amplitude=300):
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.rint(depth_mm).astype(np.uint16)).save(folder / f"{name}_depth.png")
    Image.fromarray(np.full(depth_mm.shape, amplitude, np.uint16)).save(
        folder / f"{name}_amplitude.png"
    )


@pytest.fixture
def walls(tmp_path):
    """Six frames of slanted walls at different distances sharing a column pattern (a staircase
    of 4-column blocks plus a random part: not the destriper's own model), 1.5 mm noise."""
    rng = np.random.default_rng(7)
    h, w = 80, 96
    col = 1.5 * np.repeat(rng.normal(size=w // 4), 4) + rng.normal(0, 0.8, w)
    col -= col.mean()
    yy, xx = np.mgrid[0:h, 0:w]
    for i in range(6):
        d = 1200 + 150 * i + 2.5 * xx + 1.5 * yy + col[None, :] + rng.normal(0, 1.5, (h, w))
        _pair(tmp_path / "walls", f"w{i}", d)
    scene = 2000 + 350 * ((xx > 40) & (yy > 20)) + col[None, :] + rng.normal(0, 1.5, (h, w))
    _pair(tmp_path / "scene", "s", scene)
    return tmp_path, col


def test_calibrate_recovers_the_pattern_and_clean_removes_it(walls, capsys):
    root, col = walls
    assert main(["calibrate", str(root / "walls"), str(root / "p.npz")]) == 0
    assert "calibrated 80 x 96 from 6 frame(s)" in capsys.readouterr().out
    pattern = read_pattern(root / "p.npz")
    est = pattern.column_offset.numpy() * 1e3  # metres -> mm
    # the high-pass part the calibration can identify (slower offsets are the scene's shape)
    fast = col - np.convolve(col, np.ones(31) / 31, mode="same")
    assert np.corrcoef(est, fast)[0, 1] > 0.9
    out = root / "out"
    assert main(["clean", str(root / "scene"), str(out), "--pattern", str(root / "p.npz")]) == 0
    text = capsys.readouterr().out
    assert "fixed pattern (FixedPatternCorrection)" in text.splitlines()[1]
    rec = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    cols = next(r for r in rec if r.get("status") == "done")["report"]["stripes"]["columns"]
    assert 10 * np.log10(cols["before_mm2"] / cols["after_mm2"]) >= 10.0
    saved = (out / "clean.toml").read_text()
    assert f'pattern = "{root / "p.npz"}"' in saved


def test_calibrate_and_pattern_errors(walls, capsys):
    root, _ = walls
    assert main(["calibrate", str(root / "walls"), str(root / "p.npz")]) == 0
    capsys.readouterr()
    status = main(["calibrate", str(root / "walls"), str(root / "p.npz")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "exists" in err[0]
    status = main(["calibrate", str(root / "walls"), str(root / "q.npz"), "--domain", "complex"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and "modulation frequency" in err[0]
    status = main(["clean", str(root / "scene"), str(root / "o1"), "--pattern", "nope.npz"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and "pattern file not found" in err[0] and not (root / "o1").exists()
    # a pattern of another frame size: refused when the stage is measured (nothing written) ...
    _pair(root / "small", "t", np.full((40, 48), 1500.0))
    argv = ["clean", str(root / "small"), str(root / "o2"), "--pattern", str(root / "p.npz")]
    status = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and f"pattern {root / 'p.npz'}" in err[0] and "(..., 80, 96)" in err[0]
    assert not (root / "o2").exists()
    # ... and, with a stage that measures nothing, the file fails with the reason
    status = main([*argv, "--stage", "paper", "--no-figure"])
    text = capsys.readouterr().out
    assert status == 1 and "failed: t_depth.png: " in text and "(..., 80, 96)" in text
    assert not (root / "o2" / "t_depth.png").exists()
