"""``tof-fpn clean`` learns the fixed pattern a camera's frames of different scenes share, removes
it, and says what it learned; a still scene, a single frame or a pattern-free folder are left to
the other stages; ``tof-fpn calibrate --domain scenes`` saves the same pattern for ``--pattern``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from tof_fpn_torch.analysis import LearnedPattern, learn_folder_pattern
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.clean.pattern_file import load_pattern, read_pattern, save_pattern
from tof_fpn_torch.cli import main
from tof_fpn_torch.runtime import (
    ComplexPatternCorrection,
    FixedPatternCorrection,
    PatternCorrection,
)

H, W = 60, 84


def _scene(rng: np.random.Generator) -> np.ndarray:
    """A room corner at a random place, a box in front of it (mm)."""
    y, x = np.mgrid[0:H, 0:W].astype(float)
    x0 = rng.uniform(0.25, 0.75) * W
    z = rng.uniform(1500, 2800) + np.where(x < x0, 1, -1) * rng.uniform(3, 12) * (x - x0)
    z = z + rng.uniform(-4, 4) * (y - H / 2)
    bx, by = rng.integers(0, W - 16), rng.integers(0, H - 16)
    z[by : by + 16, bx : bx + 16] -= rng.uniform(200, 500)
    return z


def _folder(root: Path, n: int, offsets_mm: np.ndarray, seed: int, still: bool = False):
    """``n`` uint16 mm PNG pairs of different scenes (one scene when ``still``) with the
    column ``offsets_mm``; the true depths (mm)."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True)
    first = _scene(rng)
    truth = []
    for i in range(n):
        z = first if still else _scene(rng)
        amp = np.full((H, W), 150.0)
        noisy = z + offsets_mm[None, :] + rng.normal(0, 2.0, z.shape)
        Image.fromarray(np.round(noisy).astype(np.uint16)).save(root / f"f{i:02d}_depth.png")
        Image.fromarray(amp.astype(np.uint16)).save(root / f"f{i:02d}_amplitude.png")
        truth.append(z)
    return np.stack(truth)


def _offsets(seed: int, sd: float = 4.0) -> np.ndarray:
    c = np.random.default_rng(seed).normal(0, sd, W)
    return c - c.mean()


def _read(folder: Path, i: int) -> np.ndarray:
    return np.asarray(Image.open(folder / f"f{i:02d}_depth.png"), dtype=float)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def _start(out: Path) -> dict:
    return next(r for r in read_manifest(out / "manifest.jsonl") if r.get("event") == "start")


def test_clean_learns_the_folder_pattern_and_every_frame_gets_closer_to_the_truth(tmp_path):
    truth = _folder(tmp_path / "in", 8, _offsets(1), seed=2)
    report = clean(str(tmp_path / "in"), str(tmp_path / "out"), figure=False)
    assert report.status == 0
    assert "fixed pattern learned from 8 frames of 8 scenes: columns" in report.stage
    for i in range(8):
        before = _rms(_read(tmp_path / "in", i) - truth[i])
        after = _rms(_read(tmp_path / "out", i) - truth[i])
        # input: 4 mm columns + 2 mm noise + rounding (~3.9-4.5 mm); the oracle leaves 2.0 mm;
        # the columns' lowest frequencies stay (a scene hides them): ~2.4 mm
        assert after < 0.7 * before, (i, before, after)
    learned = _start(tmp_path / "out")["pipeline"]["learned"]
    assert learned["scenes"] == 8 and learned["parts"]["columns"]["factor"] > 0.9


def test_a_still_scene_is_left_to_the_single_frame_stages_and_the_line_says_so(tmp_path):
    _folder(tmp_path / "in", 8, _offsets(1), seed=3, still=True)
    report = clean(str(tmp_path / "in"), str(tmp_path / "out"), figure=False)
    assert "no fixed pattern learned from 8 frame(s): a still scene: 1 distinct scene(s)" in (
        report.stage
    )
    assert _start(tmp_path / "out")["pipeline"]["pattern"] is None


def test_a_pattern_free_folder_comes_out_byte_for_byte(tmp_path):
    _folder(tmp_path / "in", 8, np.zeros(W), seed=4)
    report = clean(str(tmp_path / "in"), str(tmp_path / "out"), figure=False)
    assert "no fixed pattern learned" in report.stage
    for f in sorted((tmp_path / "in").iterdir()):
        assert (tmp_path / "out" / f.name).read_bytes() == f.read_bytes(), f.name


def test_no_learn_and_the_paper_stage_do_not_learn(tmp_path):
    _folder(tmp_path / "in", 6, _offsets(1), seed=5)
    off = clean(str(tmp_path / "in"), str(tmp_path / "off"), CleanConfig(learn=False), figure=False)
    assert "learned" not in off.stage
    assert CleanConfig(stage="paper").values()["learn"] is False
    assert CleanConfig().values()["learn"] is True
    # a new preset on the command line over a configuration takes its own learn ...
    assert CleanConfig().replace(stage="paper").values()["learn"] is False
    # ... unless learn is chosen too
    assert CleanConfig().replace(stage="paper", learn=True).values()["learn"] is True


def test_calibrate_scenes_saves_what_clean_learns_and_pattern_applies_it(tmp_path, capsys):
    _folder(tmp_path / "a", 8, _offsets(1), seed=6)
    truth_b = _folder(tmp_path / "b", 6, _offsets(1), seed=7)
    assert (
        main(["calibrate", str(tmp_path / "a"), str(tmp_path / "p.npz"), "--domain", "scenes"]) == 0
    )
    assert "fixed pattern learned from 8 frames of" in capsys.readouterr().out
    assert isinstance(read_pattern(tmp_path / "p.npz"), LearnedPattern)
    with_file = clean(
        str(tmp_path / "b"),
        str(tmp_path / "ob"),
        CleanConfig(pattern=str(tmp_path / "p.npz")),
        figure=False,
    )
    clean(str(tmp_path / "b"), str(tmp_path / "ob2"), figure=False)  # the default
    assert "the pattern file" in with_file.stage
    for i in range(6):
        e_file = _rms(_read(tmp_path / "ob", i) - truth_b[i])
        e_default = _rms(_read(tmp_path / "ob2", i) - truth_b[i])
        e_in = _rms(_read(tmp_path / "b", i) - truth_b[i])
        assert e_file < 0.7 * e_in and e_file <= 1.05 * e_default, (i, e_in, e_file, e_default)


def test_calibrate_scenes_refuses_a_folder_without_a_pattern(tmp_path, capsys):
    _folder(tmp_path / "a", 6, np.zeros(W), seed=8)
    assert (
        main(["calibrate", str(tmp_path / "a"), str(tmp_path / "p.npz"), "--domain", "scenes"]) == 2
    )
    assert "no fixed pattern learned" in capsys.readouterr().err
    assert not (tmp_path / "p.npz").exists()


def test_a_learned_pattern_file_round_trips(tmp_path):
    rng = np.random.default_rng(0)
    scenes = np.stack([_scene(rng) for _ in range(8)]) / 1000 + rng.normal(0, 0.002, (8, H, W))
    d = torch.from_numpy(scenes)[:, None] + 0.004 * torch.cos(
        math.pi * torch.arange(W, dtype=torch.float64)
    )
    learned = learn_folder_pattern(d)
    assert learned.pattern is not None
    save_pattern(learned, tmp_path / "l.npz")
    back = read_pattern(tmp_path / "l.npz")
    assert torch.equal(back.pattern.offset_map(), learned.pattern.offset_map())
    assert back.record() == json.loads(json.dumps(learned.record()))
    x = d[:2].float()
    assert torch.equal(load_pattern(tmp_path / "l.npz")(x), learned.module()(x))


def test_pattern_correction_applies_its_parts_in_order():
    g = torch.Generator().manual_seed(1)
    offsets = FixedPatternCorrection(0.01 * torch.randn(W, generator=g), height=H)
    readout = ComplexPatternCorrection(
        torch.randn(W, generator=g), torch.randn(W, generator=g), modulation_frequency_hz=20e6
    )
    d = 2.0 + 0.01 * torch.rand(2, 1, H, W, generator=g)
    a = 50 + 100 * torch.rand(2, 1, H, W, generator=g)
    both = PatternCorrection([offsets, readout], confirm=False)
    assert torch.equal(both(d, a), readout(offsets(d, a), a))
    assert not torch.equal(both(d, a), offsets(readout(d, a), a))
    with pytest.raises(ValueError, match="at least one"):
        PatternCorrection([])
    with pytest.raises(ValueError, match="must be a Stage"):
        PatternCorrection([torch.nn.Identity()])


def test_the_espros_frames_of_one_pose_are_a_still_scene_and_come_out_unchanged(tmp_path):
    """The real ESPROS point cloud (frames of one pose, then of other distances of the same
    surface): one scene, so nothing is learned, and the depth is written as it was."""
    from conftest import real_capture

    from tof_fpn_torch import io as tio

    src = real_capture("espros_tofcam635/point_cloud_w544c005_250527_134722.h5")
    report = clean(str(src), str(tmp_path / "out"), figure=False)
    assert report.status == 0
    assert "no fixed pattern learned from 8 frame(s): a still scene" in report.stage
    got = tio.read_recording(tmp_path / "out" / "point_cloud_w544c005_250527_134722.npz")
    ref = tio.read_espros_hdf5(src)
    assert torch.equal(got.depth.nan_to_num(), ref.depth.nan_to_num())


def test_a_correction_is_applied_only_to_the_frames_whose_roughness_it_lowers():
    """Two frames of a smooth scene, one with the columns the correction removes, one without:
    the first is corrected, the second (which the correction would roughen) comes out as it was,
    and the record says which."""
    g = torch.Generator().manual_seed(2)
    cols = 0.004 * torch.randn(W, generator=g, dtype=torch.float64)
    y, x = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    noise = 0.0005 * torch.randn(2, 1, H, W, generator=g, dtype=torch.float64)
    scene = 2.0 + 0.002 * x.double() + 0.001 * y.double() + noise
    frames = torch.stack([scene[0] + cols, scene[1]])
    stage = PatternCorrection([FixedPatternCorrection(cols, height=H)])
    out, rec = stage.run(frames)
    assert rec["applied"].tolist() == [1.0, 0.0]
    assert rec["roughness_change"][0] < -0.3 and rec["roughness_change"][1] > 0.3
    assert torch.equal(out[1], frames[1])
    assert torch.allclose(out[0], scene[0], atol=1e-12)
    # without the confirmation both are corrected
    forced, rec = PatternCorrection([FixedPatternCorrection(cols, height=H)], confirm=False).run(
        frames
    )
    assert rec["applied"].tolist() == [1.0, 1.0] and not torch.equal(forced[1], frames[1])


@pytest.mark.parametrize("still", [False, True])
def test_a_newcomers_sinusoid_with_column_offsets_never_gets_worse(tmp_path, still):
    """3 mm column offsets, 2 mm noise, a 300 mm sinusoid along x (period 157 px): once made
    worse by the default stage while its record claimed a gain. Scenes that move: the pattern is
    learned and every frame gets close to the oracle; one still scene: no frame gets worse."""
    rng = np.random.default_rng(0)
    h, w = 120, 320
    _, x = np.mgrid[0:h, 0:w].astype(float)
    cols = rng.normal(0, 3, w)
    (tmp_path / "in").mkdir()
    truth = []
    for i in range(6):
        phase = 0.0 if still else rng.uniform(0, 2 * np.pi)
        z = 2000 + 300 * np.sin(2 * np.pi * x / 157 + phase)
        d = np.round(z + cols[None] + rng.normal(0, 2, z.shape))
        Image.fromarray(d.astype(np.uint16)).save(tmp_path / "in" / f"f{i:02d}_depth.png")
        Image.fromarray(np.full((h, w), 200, np.uint16)).save(
            tmp_path / "in" / f"f{i:02d}_amplitude.png"
        )
        truth.append(z)
    clean(str(tmp_path / "in"), str(tmp_path / "out"), figure=False)
    for i in range(6):
        before = _rms(_read(tmp_path / "in", i) - truth[i])
        after = _rms(_read(tmp_path / "out", i) - truth[i])
        assert after <= 1.02 * before, (i, before, after)
        if not still:  # the oracle leaves 2.0 mm (noise and rounding)
            assert after < 2.4 < 0.7 * before, (i, before, after)


def test_the_calibration_frames_are_spread_over_the_folder(tmp_path):
    """A camera that stood still for its first eight files, then moved: frames spread over the
    folder show several scenes (the first eight alone would be one still scene)."""
    rng = np.random.default_rng(9)
    offsets = _offsets(1)
    (tmp_path / "in").mkdir()
    still = _scene(rng)
    for i in range(12):
        z = still if i < 8 else _scene(rng)
        noisy = z + offsets[None, :] + rng.normal(0, 2.0, z.shape)
        Image.fromarray(np.round(noisy).astype(np.uint16)).save(
            tmp_path / "in" / f"f{i:02d}_depth.png"
        )
        Image.fromarray(np.full((H, W), 150, np.uint16)).save(
            tmp_path / "in" / f"f{i:02d}_amplitude.png"
        )
    report = clean(str(tmp_path / "in"), str(tmp_path / "out"), figure=False)
    assert "fixed pattern learned from 8 frames of 4 scenes: columns" in report.stage, report.stage
