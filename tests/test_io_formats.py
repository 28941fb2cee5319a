"""The depth / amplitude file formats of ``tof_fpn_torch.io``: units, exact round trips, errors.

Every format is written and read back and compared exactly (NaN = NaN); integer files made by
the format's own library (not by us) are read and written back and compared byte for byte where
the format allows it (``.npy``, raw) and value for value plus writer determinism elsewhere.
Seeded data: uint16 mm with 0 holes, the full uint16 range included.
"""

from __future__ import annotations

import math

import h5py
import imageio.v3 as iio
import numpy as np
import pytest
import tifffile
import torch

from tof_fpn_torch import io as tio
from tof_fpn_torch.io import FormatError

T, H, W = 3, 17, 23


def _mm(seed: int = 0, frames: int = T) -> np.ndarray:
    """uint16 mm (frames, H, W) with holes (0) and both ends of the range."""
    rng = np.random.default_rng(seed)
    mm = rng.integers(1, 65536, (frames, H, W), dtype=np.uint16)
    mm[rng.random(mm.shape) < 0.1] = 0
    mm[0, 0, :3] = (1, 65535, 0)
    return mm


def _counts(seed: int = 1, frames: int = T) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 65536, (frames, H, W), dtype=np.uint16)


def _metres(mm: np.ndarray) -> torch.Tensor:
    """What every reader must return for ``mm``: float32 (T, 1, H, W) metres, NaN at 0."""
    m = (mm.astype(np.float64) / 1000.0).astype(np.float32)
    m[mm == 0] = np.nan
    return torch.from_numpy(m).unsqueeze(1)


def _same(a: torch.Tensor, b: torch.Tensor) -> None:
    assert a.dtype == b.dtype == torch.float32 and a.shape == b.shape
    torch.testing.assert_close(a, b, rtol=0, atol=0, equal_nan=True)


# --- unit conversion: uint16 mm <-> float32 metres is exact over the whole range ---------------


def test_every_uint16_mm_value_survives_metres_and_back(tmp_path):
    mm = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    path = tmp_path / "all.npy"
    np.save(path, mm)
    depth = tio.read_npy(path)
    assert depth.dtype == torch.float32 and depth.shape == (1, 1, 256, 256)
    assert math.isnan(float(depth[0, 0, 0, 0]))  # 0 mm is invalid -> NaN
    assert float(depth[0, 0, 0, 1]) == pytest.approx(0.001)
    assert float(depth[0, 0, -1, -1]) == float(np.float32(65.535))
    out = tmp_path / "back.npy"
    tio.write_npy(out, depth)
    assert out.read_bytes() == path.read_bytes()


# --- round trips of every format ----------------------------------------------------------------

PAIRS = {
    "npz": ("f.npz", None),
    "h5": ("f.h5", None),
    "npy": ("f_depth.npy", "f_amplitude.npy"),
    "tiff": ("f_depth.tiff", "f_amplitude.tif"),
    "raw": ("f_depth.bin", "f_amplitude.raw"),
    "png": ("f_depth.png", "f_amplitude.png"),
}


@pytest.mark.parametrize("fmt", list(PAIRS))
def test_write_read_round_trip_is_exact(tmp_path, fmt):
    frames = 1 if fmt == "png" else T
    mm, counts = _mm(frames=frames), _counts(frames=frames)
    depth = _metres(mm)
    amplitude = torch.from_numpy(counts.astype(np.float32)).unsqueeze(1)
    depth_in, amp_in = depth.clone(), amplitude.clone()
    dp, ap = (tmp_path / n if n else None for n in PAIRS[fmt])
    tio.write_pair(dp, depth, amplitude, ap)
    _same(depth, depth_in)  # the writer does not modify its inputs
    _same(amplitude, amp_in)
    d2, a2 = tio.read_pair(dp, ap, height=H, width=W)
    _same(d2, depth)
    _same(a2, amplitude)
    # the writer is deterministic: writing what was read gives the same bytes again
    before = [p.read_bytes() for p in (dp, ap) if p is not None]
    tio.write_pair(dp, d2, a2, ap)
    assert [p.read_bytes() for p in (dp, ap) if p is not None] == before


@pytest.mark.parametrize("fmt", ["npz", "h5", "npy", "tiff"])
def test_float32_files_round_trip_exactly(tmp_path, fmt):
    rng = np.random.default_rng(2)
    depth = torch.from_numpy(rng.uniform(0.1, 9.0, (T, 1, H, W)).astype(np.float32))
    depth[0, 0, 1, 1] = math.nan
    amplitude = torch.from_numpy(rng.uniform(-1.0, 500.0, (T, 1, H, W)).astype(np.float32))
    amplitude[1, 0, 2, 2] = math.nan  # float files can hold an invalid amplitude
    dp, ap = (tmp_path / n if n else None for n in PAIRS[fmt])
    tio.write_pair(dp, depth, amplitude, ap, dtype="float32")
    d2, a2 = tio.read_pair(dp, ap)
    _same(d2, depth)
    _same(a2, amplitude)
    stored = np.load(dp) if fmt == "npy" else None
    if stored is not None:
        assert stored.dtype == np.float32 and np.isnan(stored[0, 1, 1])


def test_invalid_depth_codes_become_nan_on_read_and_zero_on_write(tmp_path):
    """valid_mask's rule: NaN, +-inf, 0 and negative depth are all "no measurement"."""
    x = np.array([[[0.5, 0.0, -1.0, np.inf, -np.inf, np.nan, 2.0]]], dtype=np.float32)
    np.save(tmp_path / "f.npy", x)
    d = tio.read_npy(tmp_path / "f.npy")
    assert d[0, 0, 0, 0] == 0.5 and d[0, 0, 0, -1] == 2.0
    assert bool(d[0, 0, 0, 1:6].isnan().all())
    tio.write_npy(tmp_path / "g.npy", torch.from_numpy(x))
    np.testing.assert_array_equal(np.load(tmp_path / "g.npy"), [[500, 0, 0, 0, 0, 0, 2000]])


def test_foreign_integer_files_round_trip(tmp_path):
    """Files written by NumPy / imageio / tifffile / h5py / tofile: read, write back, compare."""
    mm, counts = _mm(3), _counts(4)
    np.save(tmp_path / "a_depth.npy", mm)
    mm.astype("<u2").tofile(tmp_path / "a_depth.bin")
    iio.imwrite(tmp_path / "a_depth.png", mm[0])
    tifffile.imwrite(tmp_path / "a_depth.tif", mm, photometric="minisblack")
    with h5py.File(tmp_path / "a.h5", "w") as f:
        f["depth"], f["amplitude"] = mm, counts
    np.savez(tmp_path / "a.npz", depth=mm, amplitude=counts)
    expect = _metres(mm)
    for name, read, write in (
        ("a_depth.npy", tio.read_npy, tio.write_npy),
        ("a_depth.bin", lambda p: tio.read_raw(p, H, W), tio.write_raw),
        ("a_depth.png", tio.read_png, tio.write_png),
        ("a_depth.tif", tio.read_tiff, tio.write_tiff),
    ):
        d = read(tmp_path / name)
        _same(d, expect[:1] if name.endswith(".png") else expect)
        write(tmp_path / f"b{name[1:]}", d)
        if name.endswith((".npy", ".bin")):  # layout-free formats: the same bytes
            assert (tmp_path / f"b{name[1:]}").read_bytes() == (tmp_path / name).read_bytes()
    np.testing.assert_array_equal(iio.imread(tmp_path / "b_depth.png"), mm[0])
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "b_depth.tif"), mm)
    for name in ("a.h5", "a.npz"):
        d, a = tio.read_pair(tmp_path / name)
        _same(d, expect)
        assert torch.equal(a[:, 0], torch.from_numpy(counts.astype(np.float32)))
        tio.write_pair(tmp_path / f"b{name[1:]}", d, a)
        d2, a2 = tio.read_pair(tmp_path / f"b{name[1:]}")
        _same(d2, d)
        _same(a2, a)
    with h5py.File(tmp_path / "b.h5") as f:
        assert f["depth"].dtype == np.uint16 and f["depth"].attrs["unit"] == "mm"
        np.testing.assert_array_equal(f["depth"][()], mm)
    assert np.load(tmp_path / "b.npz")["depth"].dtype == np.uint16


def test_single_frames_are_stored_two_dimensional(tmp_path):
    d = _metres(_mm(frames=1))
    tio.write_npy(tmp_path / "x.npy", d)
    tio.write_tiff(tmp_path / "x.tif", d)
    assert np.load(tmp_path / "x.npy").shape == (H, W)
    assert tifffile.imread(tmp_path / "x.tif").shape == (H, W)
    assert tio.read_npy(tmp_path / "x.npy").shape == (1, 1, H, W)


def test_depth_scale_other_units(tmp_path):
    """0.1 mm units: written with depth_scale=1e-4 and read back the same; HDF5 states it."""
    mm10 = _mm(5)  # counts of 0.1 mm
    d = _metres(mm10) / 10
    tio.write_hdf5(tmp_path / "s.h5", d, torch.ones_like(d), depth_scale=1e-4)
    with h5py.File(tmp_path / "s.h5") as f:
        np.testing.assert_array_equal(f["depth"][()], mm10)
        assert f["depth"].attrs["scale_m"] == 1e-4 and f["depth"].attrs["unit"] == "0.0001 m"
    d2, _ = tio.read_hdf5(tmp_path / "s.h5")  # the attribute, not the mm default
    torch.testing.assert_close(d2, d, rtol=1e-6, atol=0, equal_nan=True)
    tio.write_raw(tmp_path / "s.bin", d, depth_scale=1e-4)
    np.testing.assert_array_equal(np.fromfile(tmp_path / "s.bin", "<u2").reshape(mm10.shape), mm10)
    d3 = tio.read_raw(tmp_path / "s.bin", H, W, depth_scale=1e-4)
    torch.testing.assert_close(d3, d, rtol=1e-6, atol=0, equal_nan=True)
    with pytest.raises(ValueError, match="depth_scale must be finite and > 0"):
        tio.read_raw(tmp_path / "s.bin", H, W, depth_scale=0.0)


def test_amplitude_uint16_is_rounded_counts(tmp_path):
    a = torch.tensor([[[[0.4, 0.6, 1.5, 65534.7]]]])
    d = torch.ones_like(a)
    tio.write_npz(tmp_path / "r.npz", d, a)
    np.testing.assert_array_equal(np.load(tmp_path / "r.npz")["amplitude"], [[0, 1, 2, 65535]])
    tio.write_npz(tmp_path / "f.npz", d, a, amplitude_dtype="float32")
    assert torch.equal(tio.read_npz(tmp_path / "f.npz")[1], a)


# --- values a file cannot hold ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("depth", "match"),
    [
        (65.536, "does not fit uint16"),
        (0.0004, "rounds to 0 units"),
    ],
)
def test_depth_outside_uint16_mm_raises(tmp_path, depth, match):
    with pytest.raises(ValueError, match=match):
        tio.write_png(tmp_path / "x.png", torch.tensor([[depth, 1.0]]))
    assert not (tmp_path / "x.png").exists()
    tio.write_npy(tmp_path / "x.npy", torch.tensor([[depth, 1.0]]), dtype="float32")  # fits


@pytest.mark.parametrize(
    ("amplitude", "match"),
    [(math.nan, "no invalid code"), (-1.0, r"\[0, 65535\]"), (65535.6, r"\[0, 65535\]")],
)
def test_amplitude_outside_uint16_raises(tmp_path, amplitude, match):
    with pytest.raises(ValueError, match=match):
        tio.write_raw(tmp_path / "a.raw", torch.tensor([[amplitude, 1.0]]), "amplitude")


def test_writer_argument_errors(tmp_path):
    d = torch.ones(1, 1, 4, 5)
    with pytest.raises(ValueError, match="dtype must be one of \\['uint16', 'float32'\\]"):
        tio.write_npy(tmp_path / "x.npy", d, dtype="uint8")
    with pytest.raises(ValueError, match="kind must be 'depth' or 'amplitude', got 'ir'"):
        tio.write_npy(tmp_path / "x.npy", d, "ir")
    with pytest.raises(ValueError, match="must be floating point.*int64"):
        tio.write_npy(tmp_path / "x.npy", torch.ones(4, 5, dtype=torch.int64))
    with pytest.raises(ValueError, match=r"shape \(H, W\), \(T, H, W\) or \(T, 1, H, W\)"):
        tio.write_npy(tmp_path / "x.npy", torch.ones(2, 2, 4, 5))
    with pytest.raises(ValueError, match="a PNG holds one frame, got 2 frames"):
        tio.write_png(tmp_path / "x.png", torch.ones(2, 1, 4, 5))
    with pytest.raises(ValueError, match="uint16 only"):
        tio.write_pair(
            tmp_path / "x_depth.png", d, d, tmp_path / "x_amplitude.png", dtype="float32"
        )
    with pytest.raises(FileNotFoundError, match="does not exist"):
        tio.write_npy(tmp_path / "no" / "x.npy", d)
    with pytest.raises(ValueError, match="unsupported file suffix '.jpg'"):
        tio.write_pair(tmp_path / "x.jpg", d, d, tmp_path / "y.jpg")
    with pytest.raises(ValueError, match="pass amplitude_path too"):
        tio.write_pair(tmp_path / "x_depth.npy", d, d)


# --- shapes that do not match -------------------------------------------------------------------


def test_depth_and_amplitude_of_different_shapes_raise(tmp_path):
    d, a = torch.ones(1, 1, 4, 5), torch.ones(1, 1, 4, 6)
    for path in ("x.npz", "x.h5"):
        with pytest.raises(ValueError, match=r"same shape, got \[1, 1, 4, 5\] and \[1, 1, 4, 6\]"):
            tio.write_pair(tmp_path / path, d, a)
    np.savez(tmp_path / "y.npz", depth=np.ones((4, 5), np.uint16), amplitude=np.ones((5, 4)))
    with pytest.raises(ValueError, match=r"same shape, got \[1, 4, 5\] and \[1, 5, 4\]"):
        tio.read_npz(tmp_path / "y.npz")
    with h5py.File(tmp_path / "y.h5", "w") as f:
        f["depth"], f["amplitude"] = np.ones((2, 4, 5), np.uint16), np.ones((4, 5), np.uint16)
    with pytest.raises(ValueError, match="same shape"):
        tio.read_hdf5(tmp_path / "y.h5")
    iio.imwrite(tmp_path / "z_depth.png", np.ones((4, 5), np.uint16))
    iio.imwrite(tmp_path / "z_amplitude.png", np.ones((5, 5), np.uint16))
    with pytest.raises(ValueError, match="same shape"):
        tio.read_pair(tmp_path / "z_depth.png", tmp_path / "z_amplitude.png")


# --- corrupt, truncated and wrongly typed files -------------------------------------------------


def _truncate(path, keep: float = 0.5) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


@pytest.mark.parametrize("fmt", list(PAIRS))
def test_truncated_files_raise_format_errors(tmp_path, fmt):
    frames = 1 if fmt == "png" else T
    d = _metres(_mm(frames=frames))
    a = torch.from_numpy(_counts(frames=frames).astype(np.float32)).unsqueeze(1)
    dp, ap = (tmp_path / n if n else None for n in PAIRS[fmt])
    tio.write_pair(dp, d, a, ap)
    _truncate(dp)
    with pytest.raises(FormatError, match=str(dp.name)):
        tio.read_pair(dp, ap, height=H, width=W)


def test_garbage_files_raise_format_errors(tmp_path):
    for name in ("g.npz", "g.h5", "g_depth.png", "g_depth.tif", "g_depth.npy"):
        (tmp_path / name).write_bytes(b"not a file of this format at all" * 10)
    for name, call in (
        ("g.npz", tio.read_npz),
        ("g.h5", tio.read_hdf5),
        ("g_depth.png", tio.read_png),
        ("g_depth.tif", tio.read_tiff),
        ("g_depth.npy", tio.read_npy),
    ):
        with pytest.raises(FormatError, match=r"cannot read .*g.*truncated or corrupt"):
            call(tmp_path / name)


def test_raw_size_errors(tmp_path):
    np.zeros(H * W * 2 + 1, np.uint16).tofile(tmp_path / "r.bin")
    with pytest.raises(FormatError, match=r"not a whole number of 17 x 23 uint16 frames"):
        tio.read_raw(tmp_path / "r.bin", H, W)
    np.ones(H * W * 2, np.uint16).tofile(tmp_path / "r.bin")
    with pytest.raises(FormatError, match=r"expected 3 frame\(s\)"):
        tio.read_raw(tmp_path / "r.bin", H, W, frames=3)
    assert tio.read_raw(tmp_path / "r.bin", H, W).shape == (2, 1, H, W)
    with pytest.raises(ValueError, match="height must be an int >= 1"):
        tio.read_raw(tmp_path / "r.bin", 0, W)
    with pytest.raises(FileNotFoundError, match="raw depth file not found"):
        tio.read_raw(tmp_path / "missing.bin", H, W)


@pytest.mark.parametrize(
    ("data", "dtype"),
    [
        (np.array([["a", "b"]], dtype="S1"), r"\|S1"),
        (np.ones((2, 3), np.complex64), "complex64"),
        (np.ones((2, 3), bool), "bool"),
    ],
)
def test_hdf5_wrong_dtype_raises(tmp_path, data, dtype):
    with h5py.File(tmp_path / "w.h5", "w") as f:
        f["depth"], f["amplitude"] = data, np.ones(data.shape, np.uint16)
    with pytest.raises(FormatError, match=f"dataset 'depth' has dtype {dtype}"):
        tio.read_hdf5(tmp_path / "w.h5")


def test_hdf5_layout_errors(tmp_path):
    with h5py.File(tmp_path / "l.h5", "w") as f:
        f.create_group("depth")
        f["amplitude"] = np.ones((2, 3))
    with pytest.raises(FormatError, match="'depth' is a Group, not a dataset"):
        tio.read_hdf5(tmp_path / "l.h5")
    with pytest.raises(FormatError, match=r"no dataset 'range'; the file holds \['amplitude'"):
        tio.read_hdf5(tmp_path / "l.h5", depth_key="range")
    with h5py.File(tmp_path / "s.h5", "w") as f:
        f["depth"], f["amplitude"] = np.ones((2, 3), np.uint16), np.ones((2, 3))
        f["depth"].attrs["scale_m"] = -1.0
    with pytest.raises(FormatError, match=r"\[depth\].attrs\['scale_m'\]: not a scale"):
        tio.read_hdf5(tmp_path / "s.h5")
    d, _ = tio.read_hdf5(tmp_path / "s.h5", depth_scale=0.5)  # the argument wins
    assert bool((d == 0.5).all())


def test_npz_layout_errors(tmp_path):
    np.savez(tmp_path / "k.npz", depth=np.ones((2, 3), np.uint16))
    with pytest.raises(FormatError, match=r"no array\(s\) \['amplitude'\]"):
        tio.read_npz(tmp_path / "k.npz")
    np.savez(tmp_path / "o.npz", depth=np.array([{"a": 1}], dtype=object), amplitude=np.ones(1))
    with pytest.raises(FormatError, match="cannot read"):  # pickles are refused
        tio.read_npz(tmp_path / "o.npz")
    np.save(tmp_path / "n.npy", np.ones((2, 3)))
    with pytest.raises(FormatError, match="an .npy file, not an .npz archive"):
        tio.read_npz(tmp_path / "n.npy")
    np.savez(tmp_path / "s.npz", depth=np.array(["x"]), amplitude=np.ones(1))
    with pytest.raises(FormatError, match="dtype <U1 is not a depth / amplitude dtype"):
        tio.read_npz(tmp_path / "s.npz")
    np.savez(tmp_path / "d.npz", depth=np.ones((2, 3, 4, 5)), amplitude=np.ones((2, 3, 4, 5)))
    with pytest.raises(FormatError, match=r"expected an \(H, W\) or \(T, H, W\) array"):
        tio.read_npz(tmp_path / "d.npz")


def test_colour_images_are_refused(tmp_path):
    rgb = np.zeros((4, 5, 3), np.uint8)
    iio.imwrite(tmp_path / "c.png", rgb)
    with pytest.raises(FormatError, match=r"single-channel integer.*\(4, 5, 3\)"):
        tio.read_png(tmp_path / "c.png")
    tifffile.imwrite(tmp_path / "c.tif", rgb, photometric="rgb")
    with pytest.raises(FormatError, match="axes 'YXS'"):
        tio.read_tiff(tmp_path / "c.tif")
    # tifffile's default for a (3, H, W) uint16 array is an RGB image, not three frames
    tifffile.imwrite(tmp_path / "p.tif", np.ones((3, 4, 5), np.uint16), photometric="rgb")
    with pytest.raises(FormatError, match="axes 'SYX'"):
        tio.read_tiff(tmp_path / "p.tif")


# --- frames with no valid pixel -----------------------------------------------------------------


def test_nan_only_frames_raise_unless_allowed(tmp_path):
    iio.imwrite(tmp_path / "e_depth.png", np.zeros((4, 5), np.uint16))
    iio.imwrite(tmp_path / "e_amplitude.png", np.ones((4, 5), np.uint16))
    with pytest.raises(ValueError, match=r"frame\(s\) \[0\] of 1 have no valid pixel"):
        tio.read_png(tmp_path / "e_depth.png")
    with pytest.raises(ValueError, match="no valid pixel"):
        tio.read_pair(tmp_path / "e_depth.png", tmp_path / "e_amplitude.png")
    d = tio.read_png(tmp_path / "e_depth.png", allow_empty=True)
    assert bool(d.isnan().all())
    # one empty frame of three is named; an all-NaN amplitude empties a frame too
    depth = torch.rand(3, 1, 4, 5) + 0.5
    depth[1] = math.nan
    tio.write_npz(tmp_path / "e.npz", depth, torch.ones_like(depth), dtype="float32")
    with pytest.raises(ValueError, match=r"frame\(s\) \[1\] of 3"):
        tio.read_npz(tmp_path / "e.npz")
    amp = torch.ones(3, 1, 4, 5)
    amp[2] = math.nan
    tio.write_hdf5(tmp_path / "e.h5", depth.nan_to_num(1.0), amp, dtype="float32")
    with pytest.raises(ValueError, match=r"frame\(s\) \[2\] of 3"):
        tio.read_hdf5(tmp_path / "e.h5")
    assert tio.read_hdf5(tmp_path / "e.h5", allow_empty=True)[1][2].isnan().all()


def test_missing_files_raise_file_not_found(tmp_path):
    for call in (tio.read_npy, tio.read_png, tio.read_tiff, tio.read_npz, tio.read_hdf5):
        with pytest.raises(FileNotFoundError, match="file not found"):
            call(tmp_path / "nothing")
