"""ESPROS TOFcam635 HDF5 files of the epc-tofcam-toolkit (``tof_fpn_torch.io.espros``), read from
the real files in tests/data/real/espros_tofcam635 (a missing file fails): found by content, the
point cloud's depth = z in metres and its amplitude in the sensor's orientation, both pixel orders,
invalid pixels, units, the amplitude-only file's reason, header sizes, ``tof-fpn clean`` and
``tof-fpn convert`` on the folder."""

from __future__ import annotations

import os
import shutil

import h5py
import numpy as np
import pytest
import torch
from conftest import real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.cli import main
from tof_fpn_torch.io import formats as F
from tof_fpn_torch.io.headers import frame_sizes
from tof_fpn_torch.io.stored import read_frame_sets

POINT_CLOUD = "espros_tofcam635/point_cloud_w544c005_250527_134722.h5"
AMPLITUDE = "espros_tofcam635/amplitude_w544c005_250527_134627.h5"
#: the amplitude file's frames with the illumination off (tests/data/real/README.md)
DARK = [*range(25, 30), *range(53, 60)]


def _raw(path):
    with h5py.File(path, "r") as f:
        return f["frames_0"][()], f["frames_1"][()], f["timestamps"][()]


def _readme_image(flat):
    """The README's reading of the point cloud: reshape to (..., 160, 60), transpose."""
    return np.swapaxes(flat.reshape(*flat.shape[:-1], 160, 60), -1, -2)


def _copy(tmp_path, name="take.h5"):
    dst = tmp_path / name
    shutil.copyfile(real_capture(POINT_CLOUD), dst)
    return dst


def _corr(a, b) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def test_the_toolkit_files_are_found_by_content_not_by_name(tmp_path):
    pc, amp = real_capture(POINT_CLOUD), real_capture(AMPLITUDE)
    assert F.format_for(pc).name == F.format_for(amp).name == "espros_hdf5"
    assert F.format_for(_copy(tmp_path, "any_name.HDF5")).name == "espros_hdf5"
    # the package's own HDF5 files, a path that does not exist, frames without the toolkit's
    # attributes: HDF5 files like any other; the frame-file tools go by suffix only
    tio.write_hdf5(tmp_path / "mine.h5", np.ones((2, 3)), np.ones((2, 3)))
    with h5py.File(tmp_path / "bare.h5", "w") as f:
        f["frames_0"], f["timestamps"] = np.ones((1, 3, 4)), np.zeros(1)
    for p in (tmp_path / "mine.h5", tmp_path / "missing.h5", tmp_path / "bare.h5"):
        assert F.format_for(p).name == "hdf5", p
    assert F.format_for(pc, by_name=False).name == "hdf5"


def test_the_point_cloud_is_z_in_metres_and_its_amplitude_in_the_sensor_orientation():
    path = real_capture(POINT_CLOUD)
    points, amp, stamps = _raw(path)
    rec = tio.read_espros_hdf5(path)
    assert rec.depth.shape == rec.amplitude.shape == (14, 1, 60, 160)
    assert rec.depth.dtype == rec.amplitude.dtype == torch.float32
    # z (not the radial distance) in metres, mirrored left-right against the README's reading
    want = (_readme_image(points[:, 2])[..., ::-1] * 1e-3).astype(np.float32)
    np.testing.assert_array_equal(rec.depth[:, 0].numpy(), want)
    np.testing.assert_array_equal(
        rec.amplitude[:, 0].numpy(), _readme_image(amp)[..., ::-1].astype(np.float32)
    )
    radial = np.linalg.norm(points, axis=1)
    assert np.median(radial / points[:, 2]) > 1.05  # the two differ: depth really is z
    assert 0.5 < float(rec.depth.nanmedian()) < 2.0  # metres, a surface about 1 m away
    assert not rec.depth.isnan().any()  # the file has no invalid pixel
    meta = rec.meta
    assert meta["camera"] == "espros_tofcam635" and meta["modulation_frequency_hz"] == 20e6
    assert meta["integration_time_us"] == 500 and meta["n_phases"] is None
    assert meta["pixel_order"] == "rot90" and meta["depth_unit"].startswith("mm")
    assert meta["start_time_s"] == stamps[0]
    np.testing.assert_allclose(rec.timestamps_s.numpy(), stamps - stamps[0])


def test_the_point_cloud_amplitude_matches_the_amplitude_file_not_its_mirror():
    """The amplitude recording of the same camera is stored in the sensor's orientation: the
    README's reading of the point cloud is its mirror image, the reader's is not."""
    with h5py.File(real_capture(AMPLITUDE), "r") as f:
        frames = f["frames_0"][()]
    lit = frames[[i for i in range(frames.shape[0]) if i not in DARK]].mean(0)
    _, amp, _ = _raw(real_capture(POINT_CLOUD))
    readme = _readme_image(amp).mean(0)
    assert _corr(readme[:, ::-1], lit) > 0.95 and _corr(readme, lit) < 0.3
    read = tio.read_espros_hdf5(real_capture(POINT_CLOUD)).amplitude[:, 0].numpy().mean(0)
    assert _corr(read, lit) > 0.95 and _corr(read[:, ::-1], lit) < 0.3


def test_a_row_by_row_point_cloud_is_read_the_same(tmp_path):
    """Newer toolkit versions store the image row by row: the reader finds the order from the
    rays and returns the same frames."""
    path = _copy(tmp_path)
    ref = tio.read_espros_hdf5(real_capture(POINT_CLOUD))
    points, amp, _ = _raw(path)
    image = _readme_image(points)[..., ::-1]  # (T, 3, 60, 160) in the sensor's orientation
    amp_image = _readme_image(amp)[..., ::-1]
    with h5py.File(path, "r+") as f:
        f["frames_0"][...] = image.reshape(14, 3, 9600)
        f["frames_1"][...] = amp_image.reshape(14, 9600)
    rec = tio.read_espros_hdf5(path)
    assert rec.meta["pixel_order"] == "row-major"
    assert torch.equal(rec.depth, ref.depth) and torch.equal(rec.amplitude, ref.amplitude)


def test_invalid_z_becomes_nan_and_an_empty_frame_is_refused(tmp_path):
    path = _copy(tmp_path)
    points, _, _ = _raw(path)
    ref = tio.read_espros_hdf5(real_capture(POINT_CLOUD))
    # pixels of frame 2 at flat indices 0..3 of the file: README image (row j, col i) with
    # flat = i * 60 + j; in the sensor's orientation column 159 - i
    bad = {0: 0.0, 1: -5.0, 2: np.nan, 3: np.inf}
    for idx, v in bad.items():
        points[2, 2, idx] = v
    points[5, 2, :] = np.nan  # frame 5: nothing valid
    with h5py.File(path, "r+") as f:
        f["frames_0"][...] = points
    with pytest.raises(ValueError, match=r"frame\(s\) \[5\]"):
        tio.read_espros_hdf5(path)
    rec = tio.read_espros_hdf5(path, allow_empty=True)
    nan = rec.depth.isnan()[:, 0]
    assert int(nan[2].sum()) == 4 and bool(nan[5].all())
    for idx in bad:
        assert bool(nan[2, idx % 60, 159 - idx // 60]), idx
    others = [t for t in range(14) if t not in (2, 5)]
    assert torch.equal(rec.depth[others], ref.depth[others])
    keep = ~nan[2]
    assert torch.equal(rec.depth[2, 0][keep], ref.depth[2, 0][keep])
    assert torch.equal(rec.amplitude, ref.amplitude)  # the amplitude is kept as stored


def test_a_point_cloud_in_metres_is_told_from_its_values_or_by_depth_scale(tmp_path):
    path = _copy(tmp_path)
    points, _, _ = _raw(path)
    with h5py.File(path, "r+") as f:
        f["frames_0"][...] = points * 1e-3
    ref = tio.read_espros_hdf5(real_capture(POINT_CLOUD))
    rec = tio.read_espros_hdf5(path)
    assert rec.meta["depth_unit"].startswith("m:")
    torch.testing.assert_close(rec.depth, ref.depth, rtol=1e-6, atol=0)
    forced = tio.read_espros_hdf5(path, depth_scale=1e-3)  # the user says mm: 1000 x smaller
    torch.testing.assert_close(forced.depth * 1e3, ref.depth, rtol=1e-6, atol=0)


def test_odd_attributes_and_timestamps_are_kept_out_of_the_way(tmp_path):
    """Timestamps that do not increase are left out (said in the meta); attributes JSON cannot
    hold (NaN, bytes) are kept as text; no modulation frequency: None."""
    path = _copy(tmp_path)
    with h5py.File(path, "r+") as f:
        f["timestamps"][3] = f["timestamps"][2]
        f.attrs["mod_frequency"] = np.nan
        f.attrs["note"] = np.bytes_(b"lab")
    rec = tio.read_espros_hdf5(path)
    assert rec.timestamps_s is None and rec.meta["timestamp_source"].startswith("left out")
    assert rec.meta["modulation_frequency_hz"] is None
    assert rec.meta["espros_attributes"]["mod_frequency"] == "nan"
    assert rec.meta["espros_attributes"]["note"] == "lab"
    tio.write_recording(tmp_path / "r.npz", rec)  # the meta is valid JSON for a recording


def test_a_region_that_does_not_match_the_pixels_is_a_format_error(tmp_path):
    path = _copy(tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["roi_width"] = 150
    with pytest.raises(tio.FormatError, match="9600 pixels per frame.*60 x 150"):
        tio.read_espros_hdf5(path)


def test_the_amplitude_file_is_refused_with_its_reason():
    path = real_capture(AMPLITUDE)
    fmt = F.format_for(path)
    for read in (
        lambda: tio.read_any_recording(path),
        lambda: read_frame_sets(path),
        lambda: fmt.read(path),
    ):
        with pytest.raises(tio.FormatError) as err:
            read()
        msg = str(err.value)
        assert msg.startswith(f"{path}: amplitude only, no depth: "), msg
        assert "'Amplitude'" in msg and "(85, 60, 160)" in msg and "\n" not in msg


def test_frame_sizes_reads_the_headers():
    assert frame_sizes(real_capture(POINT_CLOUD)) == [(60, 160)]
    assert frame_sizes(real_capture(AMPLITUDE)) == [(60, 160)]


def test_read_frame_sets_and_read_any_recording_agree():
    path = real_capture(POINT_CLOUD)
    (fs,) = read_frame_sets(path)
    rec = tio.read_any_recording(path)
    assert fs.camera == "espros_tofcam635" and fs.depth_scale == 1.0 and fs.shape == (14, 60, 160)
    np.testing.assert_array_equal(fs.depth, rec.depth[:, 0].numpy())
    np.testing.assert_array_equal(fs.amplitude, rec.amplitude[:, 0].numpy())


def _cli(argv, capsys):
    status = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return status, cap.out, cap.err.strip().splitlines()


def test_clean_the_espros_folder_cleans_the_point_cloud_and_names_the_amplitude_files_reason(
    tmp_path, capsys
):
    src = real_capture(POINT_CLOUD).parent
    out = tmp_path / "out"
    status, stdout, err = _cli(["clean", src, out], capsys)
    assert status == 1 and "cleaned 1 file(s) (14 frames)" in stdout, (stdout, err)
    assert err[-1].startswith("tof-fpn clean: error: 1 of 2 file(s) failed"), err
    stage = [
        line for line in stdout.splitlines() if "point_cloud_w544c005" in line and "stage" in line
    ]
    assert len(stage) == 1 and "camera espros_tofcam635" in stage[0], stdout
    records = {
        r["file"]: r for r in read_manifest(os.path.join(out, "manifest.jsonl")) if "file" in r
    }
    pc, amp = os.path.basename(POINT_CLOUD), os.path.basename(AMPLITUDE)
    assert records[pc]["status"] == "done" and records[pc]["outputs"] == [pc[:-3] + ".npz"]
    reason = records[amp]["error"]
    assert records[amp]["status"] == "failed" and "amplitude only, no depth: " in reason
    assert f"failed: {amp}: {reason}" in stdout.splitlines()
    got = tio.read_recording(out / (pc[:-3] + ".npz"))
    ref = tio.read_espros_hdf5(real_capture(POINT_CLOUD))
    assert got.depth.shape == ref.depth.shape and torch.equal(got.amplitude, ref.amplitude)
    assert torch.equal(got.depth.isnan(), ref.depth.isnan())
    assert got.meta["camera"] == "espros_tofcam635" and torch.equal(
        got.timestamps_s, ref.timestamps_s
    )
    assert sorted(p.name for p in out.iterdir() if p.suffix in (".h5", ".npz")) == [
        pc[:-3] + ".npz"
    ]


def test_convert_writes_the_point_cloud_as_a_recording(tmp_path, capsys):
    out = tmp_path / "rec"
    status, stdout, err = _cli(["convert", real_capture(POINT_CLOUD), out], capsys)
    assert status == 0 and err == [] and "camera espros_tofcam635" in stdout, (stdout, err)
    rec = tio.read_recording(out / "point_cloud_w544c005_250527_134722.npz")
    ref = tio.read_espros_hdf5(real_capture(POINT_CLOUD))
    assert torch.equal(rec.depth, ref.depth) and rec.meta["modulation_frequency_hz"] == 20e6
