"""``tof-fpn clean`` with its defaults on a real camera's own files, handed over as a user has them:
the ADI ADTF3175 wall as a uint16-mm PNG pair, the Azure Kinect ``.mkv`` as it is; and on
stripe-free frames of odd, tiny and large sizes (they must come out as they went in)."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import torch
from PIL import Image

from tof_fpn_torch import io as tio
from tof_fpn_torch.analysis import column_stripe_energy, lowpass_change
from tof_fpn_torch.analysis.stripe_energy import structure_mask
from tof_fpn_torch.cli import main
from tof_fpn_torch.sim import add_depth_noise, planar_scene, synthetic_scene


def _png_pair(folder, name, depth_mm: np.ndarray, amplitude: np.ndarray) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(depth_mm.astype(np.uint16)).save(folder / f"{name}_depth.png")
    Image.fromarray(amplitude.astype(np.uint16)).save(folder / f"{name}_amplitude.png")


def _adi_energy(depth_m: torch.Tensor, region: torch.Tensor) -> float:
    """docs/destripe.md's measure: rows 0..415 (top 0..207 / bottom 208..415), columns 8..503,
    away from the cable (a 15-column high-pass beyond 4 mm, dilated by 6 px)."""
    return float(column_stripe_energy(depth_m, region, width=9, split=208).covariance)


def test_default_clean_removes_the_adi_walls_stripes_from_its_png_pair(real_data, tmp_path, capsys):
    depth, ir = real_data.adi_wall()  # float32 mm, counts
    _png_pair(tmp_path / "adi", "wall", depth[0, 0].numpy(), ir[0, 0].numpy())
    status = main(["clean", str(tmp_path / "adi"), str(tmp_path / "out"), "--quiet"])
    out = capsys.readouterr().out
    assert status == 0
    raw_in = np.asarray(Image.open(tmp_path / "adi" / "wall_depth.png"))
    raw_out = np.asarray(Image.open(tmp_path / "out" / "wall_depth.png"))
    assert raw_out.dtype == np.uint16 and np.array_equal(raw_in == 0, raw_out == 0)
    d_in = torch.from_numpy(np.where(raw_in > 0, raw_in * 1e-3, np.nan))[None, None]
    d_out = torch.from_numpy(np.where(raw_out > 0, raw_out * 1e-3, np.nan))[None, None]
    region = structure_mask(d_in, 4e-3, width=15, dilate=6)
    region[..., 416:, :] = False
    region[..., :8] = False
    region[..., -8:] = False
    reduction = 10 * math.log10(_adi_energy(d_in, region) / _adi_energy(d_out, region))
    assert reduction >= 10.0, reduction  # measured 13-16 dB (the uint16 output, dithered)
    assert 1e3 * float(lowpass_change(d_in, d_out)) < 0.5
    # the record: what was measured, what was done, and a figure
    assert "destripe" in out.splitlines()[1] and "stripes found in 1" in out
    assert "column stripe energy down" in out and (tmp_path / "out" / "report.png").is_file()
    rec = [json.loads(x) for x in (tmp_path / "out" / "manifest.jsonl").read_text().splitlines()]
    report = next(r for r in rec if r.get("status") == "done")["report"]
    assert report["found"] and report["stripes"]["columns"]["z"] > 10
    cols = report["stripes"]["columns"]
    assert 10 * math.log10(cols["before_mm2"] / cols["after_mm2"]) >= 10.0
    start = next(r for r in rec if r.get("event") == "start")
    assert start["pipeline"]["destripe"] is not None and start["pipeline"]["notch"] is None


def test_nearest_rounding_would_have_lost_the_correction(real_data, tmp_path):
    """The same pair with --rounding nearest: the sub-millimetre offsets round back to the input
    (the failure dithering mends), so the stripe energy stays within 1 dB."""
    depth, ir = real_data.adi_wall()
    _png_pair(tmp_path / "adi", "wall", depth[0, 0].numpy(), ir[0, 0].numpy())
    assert main(["clean", str(tmp_path / "adi"), str(tmp_path / "o"), "--quiet",
                 "--rounding", "nearest", "--no-figure"]) == 0  # fmt: skip
    raw_in = np.asarray(Image.open(tmp_path / "adi" / "wall_depth.png")).astype(np.float64)
    raw_out = np.asarray(Image.open(tmp_path / "o" / "wall_depth.png")).astype(np.float64)
    d_in = torch.from_numpy(np.where(raw_in > 0, raw_in * 1e-3, np.nan))[None, None]
    d_out = torch.from_numpy(np.where(raw_out > 0, raw_out * 1e-3, np.nan))[None, None]
    region = structure_mask(d_in, 4e-3, width=15, dilate=6)
    region[..., 416:, :] = False
    reduction = 10 * math.log10(_adi_energy(d_in, region) / _adi_energy(d_out, region))
    assert reduction < 3.0, reduction


def test_default_clean_takes_the_azure_kinect_mkv_as_it_is(real_data, tmp_path, capsys):
    src = tmp_path / "rec"
    src.mkdir()
    shutil.copyfile(real_data.root / "azure_kinect" / "desk_recording.mkv", src / "desk.mkv")
    assert main(["clean", str(src / "desk.mkv"), str(tmp_path / "out"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[1].startswith("stage auto, measured on")
    assert "camera azure_kinect" in out.splitlines()[1]
    rec_in = tio.read_azure_kinect_mkv(src / "desk.mkv")
    rec_out = tio.read_recording(tmp_path / "out" / "desk.npz")
    assert rec_out.depth.shape == rec_in.depth.shape and rec_out.meta["camera"] == "azure_kinect"
    assert torch.equal(rec_out.depth.isnan(), rec_in.depth.isnan())


@pytest.mark.parametrize("size", [(5, 7), (33, 47), (204, 204), (191, 255), (600, 801)])
def test_stripe_free_frames_come_out_as_they_went_in(size, tmp_path):
    """No stripes: the default stage measures nothing to do, and every output file is the input
    byte for byte (so well under the 0.1 dB of the never-hurts rule), at every size."""
    h, w = size
    folder = tmp_path / "in"
    for i, maker in enumerate((synthetic_scene, planar_scene)):
        sc = maker(max(h, 16), max(w, 16), seed=40 + i)
        g = torch.Generator().manual_seed(i)
        x = add_depth_noise(sc.depth, sc.amplitude, 0.3**2, amplitude_floor=5.0, generator=g)
        d = np.rint(np.nan_to_num(x[0, 0, :h, :w].numpy(), nan=0.0) * 1e3).clip(0, 65535)
        _png_pair(folder, f"f{i}", d, np.rint(sc.amplitude[0, 0, :h, :w].numpy()))
    assert main(["clean", str(folder), str(tmp_path / "out"), "--quiet", "--no-figure"]) == 0
    for i in range(2):
        name = f"f{i}_depth.png"
        assert (tmp_path / "out" / name).read_bytes() == (folder / name).read_bytes(), (size, i)
