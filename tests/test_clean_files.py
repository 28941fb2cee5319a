"""``tof_fpn_torch.io.stored``: files read as stored and written back as they came, depth replaced.

Every format keeps its dtype, shape, units and metadata; unchanged depth gives back the same
values; invalid pixels keep their stored value; valid pixels stay valid.
"""

from __future__ import annotations

import zipfile

import h5py
import numpy as np
import pytest
import tifffile
import torch
from PIL import Image, PngImagePlugin

from tof_fpn_torch import io as tio
from tof_fpn_torch.io.encode import encode_depth
from tof_fpn_torch.io.stored import frame_set_tensors, read_frame_sets, write_like

RNG = np.random.default_rng(7)
DEPTH_MM = RNG.integers(500, 4000, (2, 12, 16)).astype(np.uint16)
DEPTH_MM[0, 0, 0] = 0  # invalid
AMP = RNG.integers(0, 3000, (2, 12, 16)).astype(np.uint16)


def _roundtrip(src, amp=None, **kw):
    """Read, decode, encode unchanged, write back to ``<src>.out<suffix>``; the new file's sets."""
    sets = read_frame_sets(src, amp, **kw)
    depths = {}
    for fs in sets:
        d, _ = frame_set_tensors(fs)
        depths[fs.key], clamped = encode_depth(fs, d)
        assert clamped == 0
        np.testing.assert_array_equal(depths[fs.key], fs.depth)
    dst = src.with_name("out" + src.name)
    write_like(src, dst, depths, sets)
    return dst


def test_png_keeps_mode_text_and_pixels(tmp_path):
    src, amp = tmp_path / "a_depth.png", tmp_path / "a_amplitude.png"
    info = PngImagePlugin.PngInfo()
    info.add_text("camera", "adtf3175")
    Image.fromarray(DEPTH_MM[0]).save(src, pnginfo=info)
    Image.fromarray(AMP[0]).save(amp)
    dst = _roundtrip(src, amp)
    with Image.open(dst) as im:
        assert im.mode == "I;16" and im.info["camera"] == "adtf3175"
        np.testing.assert_array_equal(np.asarray(im), DEPTH_MM[0])


def test_npz_keeps_other_arrays_and_entry_dates(tmp_path):
    rec = tio.Recording(
        tio.read_npz(_npz(tmp_path))[0],
        torch.from_numpy(AMP.astype(np.float32)).unsqueeze(1),
        {"modulation_frequency_hz": 20e6, "integration_time_us": None, "n_phases": 4},
    )
    src = tmp_path / "rec.npz"
    tio.write_recording(src, rec)
    dst = _roundtrip(src)
    with zipfile.ZipFile(src) as a, zipfile.ZipFile(dst) as b:
        assert [i.filename for i in a.infolist()] == [i.filename for i in b.infolist()]
        assert [i.date_time for i in a.infolist()] == [i.date_time for i in b.infolist()]
        for name in a.namelist():
            assert a.read(name) == b.read(name)  # float32 depth: metres back exactly
    assert dst.read_bytes() == src.read_bytes()
    assert tio.read_recording(dst).meta["modulation_frequency_hz"] == 20e6


def _npz(tmp_path):
    p = tmp_path / "plain.npz"
    np.savez(p, depth=DEPTH_MM, amplitude=AMP, note=np.array("kept"))
    return p


def test_npz_from_numpy_keeps_extra_keys(tmp_path):
    src = _npz(tmp_path)
    dst = _roundtrip(src)
    with np.load(dst) as f:
        assert str(f["note"]) == "kept" and f["depth"].dtype == np.uint16
        np.testing.assert_array_equal(f["depth"], DEPTH_MM)


def test_hdf5_keeps_groups_attributes_filters(tmp_path):
    src = tmp_path / "seq.h5"
    with h5py.File(src, "w", track_order=True) as f:
        f.attrs["camera"] = "kinect"
        g = f.create_group("scan1")
        ds = g.create_dataset("depth", data=DEPTH_MM, chunks=(1, 12, 16), compression="gzip")
        ds.attrs["unit"] = "mm"
        g.create_dataset("amplitude", data=AMP)
        f.create_dataset("depth", data=DEPTH_MM[0].astype(np.float32) / 1000)
        f.create_dataset("amplitude", data=AMP[0].astype(np.float32))
        f.create_dataset("calibration", data=np.arange(5.0))
    sets = read_frame_sets(src)
    assert sorted(fs.key for fs in sets) == ["", "scan1"]
    dst = _roundtrip(src)
    with h5py.File(dst) as f:
        assert f.attrs["camera"] == "kinect" and list(f["calibration"][()]) == list(range(5))
        ds = f["scan1/depth"]
        assert ds.compression == "gzip" and ds.chunks == (1, 12, 16) and ds.attrs["unit"] == "mm"
        np.testing.assert_array_equal(ds[()], DEPTH_MM)
        assert f["depth"].dtype == np.float32 and f["depth"].shape == (12, 16)
    again = tmp_path / "again.h5"
    write_like(src, again, {fs.key: fs.depth for fs in sets}, sets)
    assert again.read_bytes() == dst.read_bytes()  # deterministic


def test_tiff_npy_raw_keep_dtype_and_shape(tmp_path):
    tifffile.imwrite(
        tmp_path / "t_depth.tif", DEPTH_MM, photometric="minisblack", compression="zlib"
    )
    tifffile.imwrite(tmp_path / "t_amplitude.tif", AMP, photometric="minisblack")
    dst = _roundtrip(tmp_path / "t_depth.tif", tmp_path / "t_amplitude.tif")
    with tifffile.TiffFile(dst) as t:
        assert t.pages[0].compression == 8 and t.series[0].shape == (2, 12, 16)
    np.save(tmp_path / "n_depth.npy", DEPTH_MM[0].astype(np.float32) / np.float32(1000))
    np.save(tmp_path / "n_amplitude.npy", AMP[0])
    dst = _roundtrip(tmp_path / "n_depth.npy", tmp_path / "n_amplitude.npy")
    assert np.load(dst).dtype == np.float32 and np.load(dst).shape == (12, 16)
    DEPTH_MM.astype("<u2").tofile(tmp_path / "r_depth.bin")
    AMP.astype("<u2").tofile(tmp_path / "r_amplitude.bin")
    dst = _roundtrip(tmp_path / "r_depth.bin", tmp_path / "r_amplitude.bin", height=12, width=16)
    assert dst.read_bytes() == (tmp_path / "r_depth.bin").read_bytes()


def test_float64_files_stay_float64_at_float32_precision(tmp_path):
    """The package computes in float32: a float64 file keeps its dtype, values to 6e-8."""
    d64 = DEPTH_MM[0].astype(np.float64) / 1000 + 1e-9
    np.save(tmp_path / "n_depth.npy", d64)
    np.save(tmp_path / "n_amplitude.npy", AMP[0])
    (fs,) = read_frame_sets(tmp_path / "n_depth.npy", tmp_path / "n_amplitude.npy")
    out, _ = encode_depth(fs, frame_set_tensors(fs)[0])
    assert out.dtype == np.float64
    np.testing.assert_allclose(out[0], np.where(d64 > 0, d64, 0), rtol=1e-7)


def test_encode_keeps_invalid_and_keeps_valid_valid():
    stored = np.array([[[0, 10, 65535, 3000]]], dtype=np.uint16)
    amp = np.array([[[5, 5, 5, -1]]], dtype=np.int16)  # last pixel: invalid amplitude
    fs = tio.stored.FrameSet("", stored, amp, 1e-3, (1, 4))
    cleaned = torch.tensor([[[[1.0, -0.5, 70.0, 9.0]]]])  # 0 m -> 1 mm; 70 m -> 65535
    out, moved = encode_depth(fs, cleaned)
    assert out.tolist() == [[[0, 1, 65535, 3000]]] and moved == 2
    fsf = tio.stored.FrameSet(
        "", np.array([[[np.nan, 2.0, 3.0]]], np.float32), np.ones((1, 1, 3)), 1.0, (1, 3)
    )
    out, moved = encode_depth(fsf, torch.tensor([[[[5.0, float("nan"), -1.0]]]]))
    assert np.isnan(out[0, 0, 0]) and out[0, 0, 1:].tolist() == [2.0, 3.0] and moved == 2


@pytest.mark.parametrize(
    "name, content, needle",
    [
        ("x_depth.png", b"\x89PNG\r\n\x1a\n garbage", "cannot read"),
        ("x_depth.npy", b"\x93NUMPY\x01\x00", "cannot read"),
        ("x.npz", b"PK\x03\x04 truncated", "cannot read"),
        ("x.h5", b"\x89HDF\r\n\x1a\n", "cannot read"),
    ],
)
def test_corrupt_files_raise_format_error(tmp_path, name, content, needle):
    (tmp_path / name).write_bytes(content)
    amp = None
    if "_depth" in name:
        amp = tmp_path / name.replace("_depth", "_amplitude")
        amp.write_bytes(content)
    with pytest.raises(tio.FormatError, match=needle):
        read_frame_sets(tmp_path / name, amp)


def test_hdf5_wrong_dtype_and_shapes_are_named(tmp_path):
    p = tmp_path / "bad.h5"
    with h5py.File(p, "w") as f:
        f.create_dataset("depth", data=np.array([b"a", b"b"]))
        f.create_dataset("amplitude", data=AMP[0])
    with pytest.raises(tio.FormatError, match="dtype"):
        read_frame_sets(p)
    q = tmp_path / "shape.npz"
    np.savez(q, depth=DEPTH_MM[0], amplitude=AMP[0, :5])
    with pytest.raises(ValueError, match="same shape"):
        read_frame_sets(q)
