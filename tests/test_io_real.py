"""The file layer on the real captures in ``tests/data/real`` (README there: formats, sources).

Shapes, units and plausible values; byte-exact write-back of the integer files; the Azure Kinect
Matroska recording decoded with PyAV and checked against the bytes stored in the file. A missing
capture fails the test (never skips), like ``conftest.real_data``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.runtime import valid_mask

ADI_WALL = ("adi_adtf3175/wall_depth_u16le_512x512.bin", "adi_adtf3175/wall_ir_u16le_512x512.bin")
ADI_OFFICE = "adi_adtf3175/office_mode3_interleaved_512x512.bin"
P0 = "kinect_v2_p0/p0tables_3x424x512_u16le.dat"
MKV = "azure_kinect/desk_recording.mkv"


def test_adi_wall_depth_in_metres_and_ir_in_counts(real_data):
    depth, ir = tio.read_adi_depth_ir(real_capture(ADI_WALL[0]), real_capture(ADI_WALL[1]))
    assert depth.shape == ir.shape == (1, 1, 512, 512)
    assert depth.dtype == ir.dtype == torch.float32
    valid = valid_mask(depth)
    assert float(depth[valid].median()) == pytest.approx(0.347, abs=0.002)  # the wall, ~35 cm
    # the conftest loader (mm as float) agrees: metres = mm / 1000, 0 mm -> NaN
    mm, ir_ref = real_data.adi_wall()
    assert torch.equal(valid, mm > 0) and int((~valid).sum()) == 3  # the three holes
    torch.testing.assert_close(depth[valid], mm[valid] / 1000, rtol=1e-7, atol=0)
    assert torch.equal(ir, ir_ref) and 0 <= float(ir.min()) and float(ir.max()) < 4096  # 12 bit


def test_adi_wall_write_back_is_byte_exact(tmp_path):
    depth, ir = tio.read_adi_depth_ir(real_capture(ADI_WALL[0]), real_capture(ADI_WALL[1]))
    tio.write_raw(tmp_path / "d.bin", depth)
    tio.write_raw(tmp_path / "ir.bin", ir, "amplitude")
    assert (tmp_path / "d.bin").read_bytes() == real_capture(ADI_WALL[0]).read_bytes()
    assert (tmp_path / "ir.bin").read_bytes() == real_capture(ADI_WALL[1]).read_bytes()


def test_adi_office_interleaved(real_data, tmp_path):
    depth, conf, ab = tio.read_adi_interleaved(real_capture(ADI_OFFICE))
    assert depth.shape == conf.shape == ab.shape == (1, 1, 512, 512)
    mm, conf_ref, ab_ref = real_data.adi_office()
    valid = mm > 0
    assert torch.equal(valid_mask(depth), valid)
    assert 0.03 < float((~valid).double().mean()) < 0.1  # about 6 % invalid
    torch.testing.assert_close(depth[valid], mm[valid] / 1000, rtol=1e-7, atol=0)
    assert 1.0 < float(depth[valid].median()) < 5.0  # an office: metres, not millimetres
    assert torch.equal(conf, conf_ref) and torch.equal(ab, ab_ref)
    assert float(conf.max()) <= 255
    tio.write_adi_interleaved(tmp_path / "o.bin", depth, conf, ab)
    assert (tmp_path / "o.bin").read_bytes() == real_capture(ADI_OFFICE).read_bytes()


def test_adi_interleaved_errors(tmp_path):
    data = real_capture(ADI_OFFICE).read_bytes()
    (tmp_path / "t.bin").write_bytes(data[:-3])
    with pytest.raises(tio.FormatError, match=r"not a whole number of 512 x 512"):
        tio.read_adi_interleaved(tmp_path / "t.bin")
    d = torch.ones(1, 1, 2, 2)
    with pytest.raises(ValueError, match=r"confidence must hold integer codes in \[0, 255\]"):
        tio.write_adi_interleaved(tmp_path / "x.bin", d, d * 256, d)


def test_kinect_v2_p0_tables_in_radians(tmp_path):
    p0 = tio.read_kinect_v2_p0(real_capture(P0))
    assert p0.shape == (3, 1, 424, 512) and p0.dtype == torch.float32
    assert float(p0.min()) >= 0 and float(p0.max()) < 2 * math.pi
    raw = np.fromfile(real_capture(P0), "<u2").reshape(3, 424, 512)
    np.testing.assert_allclose(p0[:, 0].numpy(), raw * (2 * math.pi / 65536), rtol=1e-6)
    # offsets spread over the turn, not a constant or a few codes
    assert all(len(np.unique(raw[i])) > 1000 for i in range(3))
    tio.write_kinect_v2_p0(tmp_path / "p0.dat", p0)
    assert (tmp_path / "p0.dat").read_bytes() == real_capture(P0).read_bytes()
    with pytest.raises(ValueError, match=r"p0 must have shape \[3, 424, 512\]"):
        tio.write_kinect_v2_p0(tmp_path / "x.dat", p0[:2])
    (tmp_path / "short.dat").write_bytes(real_capture(P0).read_bytes()[:1000])
    with pytest.raises(tio.FormatError, match=r"expected 3 frame\(s\) of 424 x 512"):
        tio.read_kinect_v2_p0(tmp_path / "short.dat")


def test_azure_kinect_mkv_depth_and_ir():
    import av  # noqa: F401 -- a test dependency: without PyAV this fails, it does not skip

    rec = tio.read_azure_kinect_mkv(real_capture(MKV))
    assert isinstance(rec, tio.Recording)
    assert rec.depth.shape == rec.amplitude.shape == (1, 1, 576, 640)  # NFOV unbinned
    assert rec.meta["camera"] == "azure_kinect" and rec.meta["depth_mode"] == "NFOV_UNBINNED"
    assert rec.meta["ir_mode"] == "ACTIVE" and rec.meta["n_phases"] is None
    assert "CalibrationInformation" in rec.meta["calibration"]
    valid = valid_mask(rec.depth)
    assert 0.15 < float((~valid).double().mean()) < 0.35  # the camera's 0 mm codes
    med = float(rec.depth[valid].median())
    assert 0.5 < med < 3.0  # a mug on a desk, metres (mm would be ~1000)
    assert float(rec.depth[valid].min()) > 0.1 and float(rec.depth[valid].max()) < 10
    assert rec.timestamps_s.shape == (1,) and 0 <= float(rec.timestamps_s[0]) < 10
    saturated = rec.amplitude == 65535  # IR's top code: only where depth is invalid
    assert int(saturated.sum()) > 1000 and not bool((saturated & valid).any())
    # independent of PyAV's decoding: the big-endian images are stored verbatim in the file
    data = real_capture(MKV).read_bytes()
    mm = torch.where(valid, rec.depth * 1000, torch.zeros_like(rec.depth)).round()
    be_depth = mm[0, 0].numpy().astype(">u2").tobytes()
    be_ir = rec.amplitude[0, 0].numpy().astype(">u2").tobytes()
    assert data.find(be_depth) > 0 and data.find(be_ir) > 0
    assert data.find(mm[0, 0].numpy().astype("<u2").tobytes()) < 0  # byte order matters


def test_azure_kinect_mkv_errors(tmp_path):
    data = real_capture(MKV).read_bytes()
    (tmp_path / "cut.mkv").write_bytes(data[: len(data) // 3])  # the depth block is cut
    with pytest.raises(tio.FormatError, match="cut.mkv"):
        tio.read_azure_kinect_mkv(tmp_path / "cut.mkv")
    (tmp_path / "junk.mkv").write_bytes(b"\x00" * 4096)
    with pytest.raises(tio.FormatError, match="cannot read .*junk.mkv as an Azure Kinect"):
        tio.read_azure_kinect_mkv(tmp_path / "junk.mkv")
    with pytest.raises(FileNotFoundError):
        tio.read_azure_kinect_mkv(tmp_path / "none.mkv")
