"""Camera files by name (tof_fpn_torch.io.camera_files) through the stored-file interface of
``tof-fpn clean``: the vendor name pattern, ADI pairs and interleaved files written back in their
own layout, recording containers (the real Azure Kinect ``.mkv``, ROS bags) written as recordings,
the ``camera`` a file tells, and :func:`read_any_recording`."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from _bags import frames, write_realsense, write_ros2
from conftest import real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.io.camera_files import (
    is_camera_recording,
    recording_stem,
    vendor_name,
    vendor_partner,
)
from tof_fpn_torch.io.captures import ADI_INTERLEAVED_DTYPE
from tof_fpn_torch.io.encode import encode_depth
from tof_fpn_torch.io.stored import frame_set_tensors, read_frame_sets, write_like


def _write_back(src, amp=None, change=None, **kw):
    """read_frame_sets -> tensors -> (changed) -> encode_depth -> write_like to ``out_<name>``."""
    sets = read_frame_sets(src, amp, **kw)
    depths = {}
    for fs in sets:
        d, _ = frame_set_tensors(fs, allow_empty=True)
        depths[fs.key], _ = encode_depth(fs, d if change is None else change(d))
    dst = Path(src).with_name("out_" + Path(src).name)
    write_like(src, dst, depths, sets)
    return sets, dst


def test_vendor_names_and_recording_stems():
    v = vendor_name("dir/wall_depth_u16le_512x424.bin")
    assert (v.kind, v.name, v.height, v.width, v.camera) == ("depth", "wall", 512, 424, "adtf3175")
    assert vendor_name("a_b_IR_u16le_2x3.RAW").kind == "ir"
    assert vendor_name("office_mode3_interleaved_512x512.bin").name == "office_mode3"
    for other in ("wall_depth.bin", "wall_depth_u8_4x4.bin", "x_interleaved_4x4.png", "p0.dat"):
        assert vendor_name(other) is None, other
    assert vendor_partner("w_depth_u16le_4x6.bin") == "w_ir_u16le_4x6.bin"
    assert vendor_partner("w_IR_u16le_4x6.raw") == "w_DEPTH_u16le_4x6.raw"
    assert vendor_partner("w_interleaved_4x6.bin") is None
    stems = ("a.mkv", "b_depth.png", "w_ir_u16le_4x6.bin", "rec.npz", "bag_dir/", "c_amplitude.tif")
    assert [recording_stem(n) for n in stems] == ["a", "b", "w", "rec", "bag_dir", "c"]
    assert is_camera_recording("x.MKV") and is_camera_recording("y.db3")
    assert not is_camera_recording("z.npz")


def test_adi_pair_size_from_the_name_and_written_back_byte_for_byte(tmp_path):
    d, ir = frames((2, 4, 6)), frames((2, 4, 6), seed=1, hi=4096)
    src, amp = tmp_path / "w_depth_u16le_4x6.bin", tmp_path / "w_ir_u16le_4x6.bin"
    d.astype("<u2").tofile(src)
    ir.astype("<u2").tofile(amp)
    # the name's size wins over height / width (which other raw files of a run may need)
    sets, dst = _write_back(src, amp, height=424, width=512)
    (fs,) = sets
    assert fs.camera == "adtf3175" and fs.depth.shape == (2, 4, 6) and fs.depth_scale == 1e-3
    np.testing.assert_array_equal(fs.amplitude, ir)
    assert dst.read_bytes() == src.read_bytes()
    (tmp_path / "v_depth_u16le_5x6.bin").write_bytes(src.read_bytes())  # 96 bytes: not 5 x 6 frames
    with pytest.raises(
        tio.FormatError, match=r"v_depth_u16le_5x6\.bin: 96 bytes .*the size 5 x 6 is from its name"
    ):
        read_frame_sets(tmp_path / "v_depth_u16le_5x6.bin", amp)


def test_interleaved_file_keeps_confidence_and_ab_bytes(tmp_path):
    rng = np.random.default_rng(3)
    px = np.zeros((1, 4, 6), ADI_INTERLEAVED_DTYPE)
    px["depth"], px["confidence"], px["ab"] = (
        frames((1, 4, 6)),
        rng.integers(0, 256, (1, 4, 6)),
        frames((1, 4, 6), seed=9),
    )
    src = tmp_path / "o_interleaved_4x6.bin"
    px.tofile(src)
    sets, dst = _write_back(src, change=lambda d: d + 0.001)  # every valid pixel 1 mm further
    assert sets[0].camera == "adtf3175" and sets[0].depth.dtype == np.uint16
    out = np.fromfile(dst, ADI_INTERLEAVED_DTYPE).reshape(1, 4, 6)
    assert dst.stat().st_size == src.stat().st_size
    np.testing.assert_array_equal(out["confidence"], px["confidence"])
    np.testing.assert_array_equal(out["ab"], px["ab"])
    valid = px["depth"] > 0
    np.testing.assert_array_equal(out["depth"][valid], px["depth"][valid] + 1)
    np.testing.assert_array_equal(out["depth"][~valid], 0)


def test_real_adi_files_as_stored(tmp_path):
    names = ("wall_depth_u16le_512x512.bin", "wall_ir_u16le_512x512.bin")
    office = "office_mode3_interleaved_512x512.bin"
    for name in (*names, office):  # copies: the shared folder is read-only
        (tmp_path / name).write_bytes(real_capture(f"adi_adtf3175/{name}").read_bytes())
    wall, ir_path = tmp_path / names[0], tmp_path / names[1]
    (fs,), dst = _write_back(wall, ir_path)
    depth, ir = tio.read_adi_depth_ir(wall, ir_path)
    d, a = frame_set_tensors(fs)
    assert torch.equal(d.isnan(), depth.isnan()) and torch.equal(d.nan_to_num(), depth.nan_to_num())
    assert torch.equal(a, ir) and dst.read_bytes() == wall.read_bytes()  # unchanged: same bytes
    (fs,), dst = _write_back(tmp_path / office)
    depth, _, ab = tio.read_adi_interleaved(tmp_path / office)
    d, a = frame_set_tensors(fs)
    assert torch.equal(d.isnan(), depth.isnan()) and torch.equal(d.nan_to_num(), depth.nan_to_num())
    assert torch.equal(a, ab) and dst.read_bytes() == (tmp_path / office).read_bytes()


def test_real_mkv_is_a_frame_set_and_comes_back_as_a_recording(tmp_path):
    mkv = real_capture("azure_kinect/desk_recording.mkv")
    rec = tio.read_azure_kinect_mkv(mkv)
    (fs,) = read_frame_sets(mkv, height=1, width=1, depth_scale=0.5)  # neither applies to .mkv
    assert fs.camera == "azure_kinect" and fs.depth.dtype == np.float32 and fs.depth_scale == 1.0
    assert (
        fs.meta["depth_mode"] == "NFOV_UNBINNED"
        and fs.timestamps_s.tolist() == rec.timestamps_s.tolist()
    )
    copy = tmp_path / "desk.mkv"
    copy.write_bytes(mkv.read_bytes())
    _, dst = _write_back(copy)
    back = tio.read_recording(dst)
    assert torch.equal(back.depth.nan_to_num(), rec.depth.nan_to_num())
    assert torch.equal(back.depth.isnan(), rec.depth.isnan()) and torch.equal(
        back.amplitude, rec.amplitude
    )
    assert back.meta == {**rec.meta, "source": "desk.mkv"} and torch.equal(
        back.timestamps_s, rec.timestamps_s
    )


def test_bags_are_frame_sets_with_their_camera(tmp_path):
    d, ir = frames(), frames(seed=1, hi=250, dtype=np.uint8)
    bag = write_ros2(tmp_path / "b2", {"/depth": (d, "16UC1"), "/ir": (ir, "mono8")})
    (fs,) = read_frame_sets(bag)
    assert fs.camera is None and fs.meta["source_format"] == "ros2_bag"
    _, dst = _write_back(bag, change=lambda x: x * 2)
    back = tio.read_recording(dst)
    want = torch.from_numpy(np.where(d > 0, d * 2e-3, np.nan).astype(np.float32)).unsqueeze(1)
    torch.testing.assert_close(back.depth, want, equal_nan=True, rtol=1e-6, atol=0)
    rs = write_realsense(tmp_path / "rs.bag", d, ir)
    assert read_frame_sets(rs)[0].camera == "realsense"
    with pytest.raises(ValueError, match="amplitude_path must be None"):
        read_frame_sets(rs, tmp_path / "x.png")


def test_a_recording_npz_states_its_camera(tmp_path):
    rec = tio.read_ros_bag(
        write_realsense(tmp_path / "rs.bag", frames(), frames(hi=250, dtype=np.uint8))
    )
    tio.write_recording(tmp_path / "rs.npz", rec)
    assert read_frame_sets(tmp_path / "rs.npz")[0].camera == "realsense"
    tio.write_npz(tmp_path / "plain.npz", rec.depth, rec.amplitude)
    assert read_frame_sets(tmp_path / "plain.npz")[0].camera is None


def test_read_any_recording(tmp_path):
    d, ir = frames((1, 4, 6)), frames((1, 4, 6), seed=1)
    d.astype("<u2").tofile(tmp_path / "w_depth_u16le_4x6.bin")
    ir.astype("<u2").tofile(tmp_path / "w_ir_u16le_4x6.bin")
    rec = tio.read_any_recording(
        tmp_path / "w_depth_u16le_4x6.bin", tmp_path / "w_ir_u16le_4x6.bin"
    )
    assert rec.meta["camera"] == "adtf3175" and "ADTF3175" in rec.meta["amplitude_unit"]
    assert rec.meta["source"] == "w_depth_u16le_4x6.bin" and rec.depth.shape == (1, 1, 4, 6)
    raw = torch.rand(1, 4, 4, 6)
    full = rec.replace(raw=raw, meta={**rec.meta, "n_phases": 4})
    tio.write_recording(tmp_path / "full.npz", full)
    assert torch.equal(tio.read_any_recording(tmp_path / "full.npz").raw, raw)  # kept whole
    with h5py.File(tmp_path / "two.h5", "w") as f:
        for g in ("a", "b"):
            f[f"{g}/depth"], f[f"{g}/amplitude"] = d, ir
    with pytest.raises(ValueError, match=r"two\.h5 holds 2 depth / amplitude groups \['a', 'b'\]"):
        tio.read_any_recording(tmp_path / "two.h5")
