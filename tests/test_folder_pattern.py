"""A camera's fixed pattern learned from its folder's frames of different scenes
(:mod:`tof_fpn_torch.analysis.folder_pattern`, ``tof-fpn clean --learn-pattern``): learned where
held-out scenes confirm it, nothing from a still camera or a pattern-free camera."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from tof_fpn_torch import io as tio
from tof_fpn_torch.analysis.folder_pattern import distinct_scenes, learn_fixed_pattern
from tof_fpn_torch.cli import main

H, W = 60, 80


def _scene(k: int, g: torch.Generator) -> torch.Tensor:
    """(H, W) metres: a room corner (a kink) with a box in front, a different pose per ``k``."""
    y, x = torch.meshgrid(
        torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij"
    )
    corner = 10 + 50 * torch.rand(1, generator=g, dtype=torch.float64)
    wall = 2.5 + 0.012 * (x - corner).abs() + 0.004 * (k - 3) * (y - H / 2) / 10
    top, left = (
        int(torch.randint(5, 30, (1,), generator=g)),
        int(torch.randint(5, 50, (1,), generator=g)),
    )
    box = torch.zeros(H, W, dtype=torch.bool)
    box[top : top + 18, left : left + 20] = True
    return torch.where(box, wall - 0.6 - 0.002 * x, wall)


def _frames(
    n: int, pattern: torch.Tensor, still: bool = False, noise: float = 0.0015, seed: int = 0
):
    g = torch.Generator().manual_seed(seed)
    truth = [
        _scene(0 if still else k, torch.Generator().manual_seed(seed * 100 + (0 if still else k)))
        for k in range(n)
    ]
    truth = torch.stack(truth)[:, None]
    d = truth + pattern + noise * torch.randn(truth.shape, generator=g, dtype=torch.float64)
    d[:, :, 7, 9] = math.nan  # a hole
    return d, truth


def _columns(seed: int = 5, sd: float = 0.004) -> torch.Tensor:
    return sd * torch.randn(W, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _rms(x: torch.Tensor) -> float:
    x = x[torch.isfinite(x)]
    return float((x - x.mean()).square().mean().sqrt())


def test_column_offsets_are_learned_across_kinks_and_edges():
    cols = _columns()
    d, truth = _frames(8, cols)
    found = learn_fixed_pattern(d)
    assert found.scenes == 8 and found.pattern is not None, found.reason
    assert found.parts["columns"]["factor"] > 0.8 and found.parts["rows"]["factor"] == 0.0
    est = found.pattern.offset_map()
    before, after = _rms(d - truth), _rms(d - truth - est)
    assert after < 0.6 * before, (before, after)  # most of the 4 mm removed, edges not learned
    # the box edges and the corner's kink, at different places in each scene, did not leak in
    assert float(found.pattern.offset_map().abs().max()) < 4 * 0.004


def test_a_still_camera_and_a_clean_camera_teach_nothing():
    d, _ = _frames(8, _columns(), still=True)
    still = learn_fixed_pattern(d)
    assert still.pattern is None and still.scenes == 1 and "still scene" in still.reason
    assert distinct_scenes(d, torch.isfinite(d)) == [list(range(8))]
    clean, _ = _frames(8, torch.zeros(W, dtype=torch.float64), seed=3)
    none = learn_fixed_pattern(clean)
    assert none.pattern is None or none.pattern.offset_map().abs().max() < 0.0005, none.parts


def test_rows_and_pixels_are_confirmed_only_when_real():
    g = torch.Generator().manual_seed(9)
    pixels = 0.003 * torch.randn(H, W, generator=g, dtype=torch.float64)
    d, truth = _frames(8, pixels)
    found = learn_fixed_pattern(d)
    assert found.parts["pixels"]["factor"] > 0.5, found.parts
    assert _rms(d - truth - found.pattern.offset_map()) < 0.7 * _rms(d - truth)


def test_bad_arguments_say_what_is_allowed():
    d, _ = _frames(4, _columns())
    with pytest.raises(ValueError, match=r"depth must be a \(N, 1, H, W\) tensor"):
        learn_fixed_pattern(d[:, 0])
    with pytest.raises(ValueError, match="window must be an odd int >= 3, got 4"):
        learn_fixed_pattern(d, window=4)
    with pytest.raises(ValueError, match="z must be a finite number > 0"):
        learn_fixed_pattern(d, z=0)
    few = learn_fixed_pattern(d[:3])
    assert few.pattern is None and "3 distinct scene(s) in 3 frame(s), at least 4" in few.reason


def _write(folder, d: torch.Tensor) -> None:
    folder.mkdir(parents=True)
    amp = np.full((H, W), 120.0, np.float32)
    for i, frame in enumerate(d[:, 0].numpy()):
        path = folder / f"f{i}_depth.png"
        tio.write_pair(path, frame.astype(np.float32), amp, folder / f"f{i}_amplitude.png")


def _read(folder, i: int) -> torch.Tensor:
    depth, _ = tio.read_pair(folder / f"f{i}_depth.png", folder / f"f{i}_amplitude.png")
    return depth[0, 0].double()


def test_clean_learns_the_folder_pattern_and_says_what_it_learned(tmp_path, capsys):
    d, truth = _frames(8, _columns(), seed=1)
    _write(tmp_path / "in", d)
    out = tmp_path / "out"
    args = ["clean", str(tmp_path / "in"), str(out), "--learn-pattern", "--stage", "paper"]
    assert main([*args, "--notch", "off", "--quiet", "--no-figure"]) == 0
    printed = capsys.readouterr().out
    assert "learned pattern: learned from 8 scenes: columns" in printed
    start = json.loads((out / "manifest.jsonl").read_text().splitlines()[0])
    assert start["pipeline"]["learned_pattern"]["rms_mm"] > 2.0
    for i in range(8):
        before = _read(tmp_path / "in", i)
        after = _read(out, i)
        t = truth[i, 0]
        assert _rms(after - t) < 0.7 * _rms(before - t), i


def test_clean_leaves_a_still_camera_as_it_was_and_says_why(tmp_path, capsys):
    d, _ = _frames(6, _columns(), still=True, seed=2)
    _write(tmp_path / "in", d)
    out = tmp_path / "out"
    args = ["clean", str(tmp_path / "in"), str(out), "--learn-pattern", "--stage", "paper"]
    assert main([*args, "--notch", "off", "--quiet", "--no-figure"]) == 0
    printed = capsys.readouterr().out
    assert (
        "nothing to do" in printed
        and "learned pattern: a still scene: 1 distinct scene(s)" in printed
    )
    for i in range(6):
        name = f"f{i}_depth.png"
        assert (out / name).read_bytes() == (tmp_path / "in" / name).read_bytes()
