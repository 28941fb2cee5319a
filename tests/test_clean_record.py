"""Integer outputs that keep the correction (dither, a finer scale), the record of what was done,
and the errors of ``tof-fpn clean`` (one line each, naming the problem)."""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
import zlib

import numpy as np
import pytest
import torch
from PIL import Image

from tof_fpn_torch.build import suppression_from_design
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.plan import LOCK
from tof_fpn_torch.cli import main
from tof_fpn_torch.io.encode import encode_depth
from tof_fpn_torch.io.stored import FrameSet, frame_set_tensors, read_frame_sets


def _set(depth_mm: np.ndarray) -> FrameSet:
    d = depth_mm.astype(np.uint16)[None]
    return FrameSet("", d, np.full_like(d, 100), 1e-3, d.shape[1:])


def test_dither_keeps_a_sub_millimetre_column_offset_in_the_column_mean():
    """A +0.3 mm correction of one column of a uint16-mm frame: nearest rounding gives back the
    input (mean change 0), dithering keeps it in the column mean (within 0.05 mm over 400 rows);
    pixels the cleaning did not touch keep their bytes; the same input gives the same bytes."""
    rng = np.random.default_rng(0)
    depth = rng.integers(800, 3000, size=(400, 64)).astype(np.uint16)
    depth[5, 5] = 0  # an invalid pixel
    fs = _set(depth)
    before = frame_set_tensors(fs, allow_empty=True)[0].double()
    cleaned = before.clone()
    cleaned[..., 10] += 0.3e-3  # +0.3 mm on column 10
    near, _ = encode_depth(fs, cleaned, "nearest")
    dith, _ = encode_depth(fs, cleaned, "dither")
    assert np.array_equal(near, fs.depth)
    change = dith[0].astype(np.float64) - depth
    assert abs(change[:, 10].mean() - 0.3) < 0.05
    assert np.array_equal(np.delete(dith[0], 10, axis=1), np.delete(depth, 10, axis=1))
    assert dith[0, 5, 5] == 0
    again, _ = encode_depth(fs, cleaned, "dither")
    assert np.array_equal(again, dith)
    # the dither is seeded by the frame's bytes: a NumPy transcription of the rule
    u = np.random.default_rng(zlib.crc32(np.ascontiguousarray(depth).tobytes())).random(depth.shape)
    ref = np.floor(depth + 0.3 + u)[:, 10]
    assert np.array_equal(dith[0, :, 10], ref.astype(np.uint16))


def test_output_scale_is_written_and_read_back(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    d = np.full((40, 48), 1500, np.uint16)
    Image.fromarray(d).save(folder / "a_depth.png")
    Image.fromarray(np.full((40, 48), 90, np.uint16)).save(folder / "a_amplitude.png")
    cfg = CleanConfig(stage="paper", destripe="columns", output_scale=1e-4)
    assert clean(str(folder), str(tmp_path / "out"), cfg, figure=False).status == 0
    raw = np.asarray(Image.open(tmp_path / "out" / "a_depth.png"))
    assert raw.dtype == np.uint16 and int(raw[0, 0]) == 15000  # 1.5 m in 0.1 mm units
    (fs,) = read_frame_sets(tmp_path / "out" / "a_depth.png", tmp_path / "out" / "a_amplitude.png")
    assert fs.depth_scale == 1e-4  # the PNG's depth_scale_m text chunk
    # the record reads the output in its own units: a flat wall moved by nothing
    rec = next(
        json.loads(x)["report"]
        for x in (tmp_path / "out" / "manifest.jsonl").read_text().splitlines()
        if '"report"' in x
    )
    assert rec["change_rms_mm"] == 0.0 and rec["lowpass_change_mm"] == 0.0


def test_eight_bit_depth_png_is_refused_with_a_hint(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    Image.fromarray(np.full((20, 20), 200, np.uint8)).save(folder / "a_depth.png")
    Image.fromarray(np.full((20, 20), 90, np.uint16)).save(folder / "a_amplitude.png")
    with pytest.raises(ValueError, match="8-bit depth holds 0-255 units.*--depth-scale"):
        read_frame_sets(folder / "a_depth.png", folder / "a_amplitude.png")
    rep = clean(str(folder), str(tmp_path / "out"), CleanConfig(stage="paper"), figure=False)
    assert rep.failed == 1 and "8-bit depth" in rep.failures[0][1]
    assert "failed: a_depth.png: " in rep.summary()


def test_a_stage_given_numpy_arrays_says_so():
    stage = suppression_from_design()
    x = np.ones((1, 1, 8, 8), np.float32)
    with pytest.raises(TypeError, match=r"depth must be a torch.Tensor.*torch.from_numpy"):
        stage(x, x)
    with pytest.raises(TypeError, match="amplitude must be a torch.Tensor"):
        stage(torch.ones(1, 1, 8, 8), x)
    with pytest.raises(TypeError, match="x must be a torch.Tensor"):
        stage.filter(x)


def test_a_string_config_is_a_type_error(tmp_path):
    with pytest.raises(TypeError, match="config must be a CleanConfig.*str 'destripe=columns'"):
        clean(str(tmp_path), str(tmp_path / "o"), "destripe=columns")


def test_ray_missing_leaves_nothing_behind(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "in"
    folder.mkdir()
    Image.fromarray(np.full((20, 20), 1000, np.uint16)).save(folder / "a_depth.png")
    Image.fromarray(np.full((20, 20), 90, np.uint16)).save(folder / "a_amplitude.png")
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda n, *a: None if n == "ray" else real(n, *a)
    )
    status = main(["clean", str(folder), str(tmp_path / "out"), "--engine", "ray"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "pip install 'tof_fpn_torch[ray]'" in err[0]
    assert not (tmp_path / "out").exists()


def test_one_run_per_output(tmp_path):
    """A second run on an OUTPUT another run holds is refused (exit 2, one line naming the
    holder); the lock file goes when a run ends, and a lock left by a killed run is taken over."""
    folder = tmp_path / "in"
    folder.mkdir()
    Image.fromarray(np.full((20, 20), 1000, np.uint16)).save(folder / "a_depth.png")
    Image.fromarray(np.full((20, 20), 90, np.uint16)).save(folder / "a_amplitude.png")
    out = tmp_path / "out"
    out.mkdir()
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT)
    os.write(fd, b"4242")
    fcntl.flock(fd, fcntl.LOCK_EX)  # another run holds OUTPUT
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "tof_fpn_torch", "clean", str(folder), str(out)],
            capture_output=True,
            text=True,
        )
    finally:
        os.close(fd)
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert "being written by another tof-fpn clean (pid 4242)" in err[0]
    assert sorted(p.name for p in out.iterdir()) == [LOCK]  # nothing written
    # the holder is gone (a killed run's lock file, unlocked): the next run takes it over
    assert main(["clean", str(folder), str(out), "--quiet", "--no-figure"]) == 0
    assert not (out / LOCK).exists() and (out / "a_depth.png").is_file()


def test_the_record_of_a_run_that_did_nothing_says_so(tmp_path, capsys):
    folder = tmp_path / "in"
    folder.mkdir()
    rng = np.random.default_rng(1)
    Image.fromarray(rng.integers(1000, 1010, (64, 80)).astype(np.uint16)).save(
        folder / "a_depth.png"
    )
    Image.fromarray(np.full((64, 80), 90, np.uint16)).save(folder / "a_amplitude.png")
    assert main(["clean", str(folder), str(tmp_path / "out"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "nothing to do" in out.splitlines()[1]
    assert "changed 0 of 1 file(s); stripes found in 0" in out
    assert "nothing was changed" in out
    rec = [json.loads(x) for x in (tmp_path / "out" / "manifest.jsonl").read_text().splitlines()]
    done = next(r for r in rec if r.get("status") == "done")
    assert done["report"]["changed"] == 0 and not done["report"]["found"]


def test_a_raw_pair_without_its_size_names_the_flags(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    np.full((8, 8), 1000, "<u2").tofile(folder / "a_depth.bin")
    np.full((8, 8), 90, "<u2").tofile(folder / "a_amplitude.bin")
    rep = clean(str(folder), str(tmp_path / "out"), CleanConfig(stage="paper"), figure=False)
    assert rep.failed == 1
    assert "frame size is not in the file" in rep.failures[0][1]
    assert "--height / --width" in rep.failures[0][1]
