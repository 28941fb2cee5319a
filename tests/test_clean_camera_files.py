"""``tof-fpn clean`` on camera files: the real Azure Kinect ``.mkv`` and ADI vendor files (also side
by side in one folder, and beside the ESPROS HDF5 files: the point cloud cleaned, the amplitude
file failing alone), ROS 1 / ROS 2 / RealSense bags in a tree, resume on bag folders, the refusal
of a folder with nothing to clean, output names two inputs would share."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from _bags import frames, write_realsense, write_ros1, write_ros2
from conftest import handed_over, real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.clean import CleanConfig, clean
from tof_fpn_torch.clean.manifest import read_manifest
from tof_fpn_torch.cli import main
from tof_fpn_torch.io.captures import ADI_INTERLEAVED_DTYPE

ADI = ("wall_depth_u16le_512x512.bin", "wall_ir_u16le_512x512.bin")
OFFICE = "office_mode3_interleaved_512x512.bin"


def _cli(argv, capsys):
    status = main([str(a) for a in argv])
    cap = capsys.readouterr()
    return status, cap.out, cap.err.strip().splitlines()


def _records(out) -> dict[str, dict]:
    return {r["file"]: r for r in read_manifest(os.path.join(out, "manifest.jsonl")) if "file" in r}


def test_clean_the_real_mkv_gives_a_recording_of_the_same_shape(tmp_path, capsys):
    mkv = real_capture("azure_kinect/desk_recording.mkv")
    out = tmp_path / "out"
    status, stdout, err = _cli(["clean", mkv, out, "--quiet"], capsys)
    assert status == 0 and err == [] and "cleaned 1 file(s) (1 frames)" in stdout, (stdout, err)
    src = tio.read_azure_kinect_mkv(mkv)
    rec = tio.read_recording(out / "desk_recording.npz")
    assert rec.depth.shape == src.depth.shape == (1, 1, 576, 640)
    assert torch.equal(rec.depth.isnan(), src.depth.isnan())  # invalid stays invalid, valid valid
    assert torch.equal(rec.amplitude, src.amplitude) and torch.equal(
        rec.timestamps_s, src.timestamps_s
    )
    assert (
        rec.meta["camera"] == "azure_kinect" and rec.meta["calibration"] == src.meta["calibration"]
    )
    assert _records(out)["desk_recording.mkv"]["outputs"] == ["desk_recording.npz"]


def test_clean_the_real_data_folder_takes_every_camera_file(tmp_path, capsys):
    """The three camera file formats side by side (ADI pair and interleaved file, Azure Kinect
    .mkv), with the Kinect v2 P0 table and the README beside them, in one folder."""
    src = handed_over(tmp_path / "in")  # conftest.CAMERA_FILES
    out = tmp_path / "out"
    status, stdout, err = _cli(["clean", src, out, "--quiet"], capsys)
    assert status == 0 and err == [] and "cleaned 3 file(s) (3 frames)" in stdout, (stdout, err)
    assert sorted(_records(out)) == [
        f"adi_adtf3175/{OFFICE}",
        f"adi_adtf3175/{ADI[0]}",
        "azure_kinect/desk_recording.mkv",
    ]  # README.md and the Kinect v2 P0 table (.dat, not a depth frame) are not jobs
    assert (out / "azure_kinect" / "desk_recording.npz").is_file()


def test_the_espros_hdf5_files_beside_an_adi_pair(tmp_path, capsys):
    """The ESPROS TOFcam635 HDF5 files (a point cloud, amplitude frames) beside an ADI pair: the
    point cloud is cleaned into a recording .npz, the amplitude-only file fails with one line
    saying it has no depth; the pair is cleaned."""
    espros = [
        "espros_tofcam635/amplitude_w544c005_250527_134627.h5",
        "espros_tofcam635/point_cloud_w544c005_250527_134722.h5",
    ]
    src = handed_over(tmp_path / "in", [*espros, *(f"adi_adtf3175/{name}" for name in ADI)])
    out = tmp_path / "out"
    status, stdout, err = _cli(["clean", src, out, "--quiet"], capsys)
    assert status == 1 and "cleaned 2 file(s) (15 frames)" in stdout, (stdout, err)
    assert err[-1].startswith("tof-fpn clean: error: 1 of 3 file(s) failed"), err
    records = _records(out)
    assert records[f"adi_adtf3175/{ADI[0]}"]["status"] == "done"
    assert (out / "adi_adtf3175" / ADI[0]).is_file()
    assert records[espros[1]]["status"] == "done"
    assert (out / "espros_tofcam635" / "point_cloud_w544c005_250527_134722.npz").is_file()
    reason = records[espros[0]]["error"]
    assert records[espros[0]]["status"] == "failed" and "\n" not in reason, records[espros[0]]
    assert reason.startswith(f"{src / espros[0]}: amplitude only, no depth: "), reason
    assert f"failed: {espros[0]}: {reason}" in stdout.splitlines()  # the summary names it
    assert not list(out.rglob("*.h5"))  # nothing written as HDF5


def test_clean_adi_vendor_files_in_their_own_format(tmp_path, capsys):
    src = tmp_path / "adi"
    src.mkdir()
    for name in (*ADI, OFFICE):
        shutil.copyfile(real_capture(f"adi_adtf3175/{name}"), src / name)
    out = tmp_path / "out"
    # column destriping moves the wall's depth (it has column stripes): the depth really goes
    # through the pipeline and back
    status, stdout, err = _cli(["clean", src, out, "--destripe", "columns", "--quiet"], capsys)
    assert status == 0 and err == [] and "cleaned 2 file(s) (2 frames)" in stdout, (stdout, err)
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [*ADI, OFFICE, "clean.toml", "manifest.jsonl", "report.png"]
    )
    assert (out / ADI[1]).read_bytes() == (src / ADI[1]).read_bytes()  # IR: byte for byte
    d_in, d_out = (np.fromfile(p / ADI[0], "<u2") for p in (src, out))
    assert (src / ADI[0]).stat().st_size == (out / ADI[0]).stat().st_size
    assert np.array_equal(d_in == 0, d_out == 0) and (d_in != d_out).sum() > 1000
    a, b = (np.fromfile(p / OFFICE, ADI_INTERLEAVED_DTYPE) for p in (src, out))
    assert np.array_equal(a["confidence"], b["confidence"]) and np.array_equal(a["ab"], b["ab"])
    invalid = a["depth"] == 0
    assert (
        np.array_equal(b["depth"][invalid], a["depth"][invalid])
        and (b["depth"][~invalid] > 0).all()
    )


def _bag_tree(root: Path) -> dict[str, np.ndarray]:
    d = {k: frames(seed=i) for i, k in enumerate(("r1", "r2", "rs", "mc"))}
    ir = frames(seed=9, hi=250, dtype=np.uint8)
    write_ros1(root / "a" / "r1.bag", {"/depth": (d["r1"], "16UC1"), "/ir": (ir, "mono8")})
    write_ros2(root / "a" / "r2", {"/depth": (d["r2"], "16UC1"), "/ir": (ir, "mono8")})
    write_realsense(root / "rs.bag", d["rs"], ir, units=0.0001)
    bag = write_ros2(
        root / "tmp_mcap", {"/depth": (d["mc"], "16UC1"), "/ir": (ir, "mono8")}, "mcap"
    )
    (root / "b").mkdir()
    shutil.move(next(bag.glob("*.mcap")), root / "b" / "m.mcap")
    shutil.rmtree(bag)
    return d


def test_clean_a_tree_of_bags_resumes_and_redoes_a_changed_bag_folder(tmp_path, capsys):
    (tmp_path / "in" / "a").mkdir(parents=True)
    d = _bag_tree(tmp_path / "in")
    out = tmp_path / "out"
    config = CleanConfig(notch="off")  # no stage: what goes in comes out
    report = clean(str(tmp_path / "in"), str(out), config)
    assert (report.done, report.failed) == (4, 0)
    recs = _records(out)
    assert sorted(recs) == ["a/r1.bag", "a/r2", "b/m.mcap", "rs.bag"]  # a/r2/*.db3 is not a job
    assert len(recs["a/r2"]["input"]["size"]) == 3  # the folder, metadata.yaml, the .db3
    for rel, key, scale in (
        ("a/r1", "r1", 1e-3),
        ("a/r2", "r2", 1e-3),
        ("rs", "rs", 1e-4),
        ("b/m", "mc", 1e-3),
    ):
        rec = tio.read_recording(out / f"{rel}.npz")
        assert torch.equal(rec.depth.isnan(), torch.from_numpy(d[key] == 0).unsqueeze(1)), rel
        want = torch.from_numpy((d[key] * scale).astype(np.float32)).unsqueeze(1)
        assert torch.equal(rec.depth.nan_to_num(), want), rel  # the identity stage: exact
    assert tio.read_recording(out / "rs.npz").meta["camera"] == "realsense"
    again = clean(str(tmp_path / "in"), str(out), config)
    assert (again.already_done, again.done) == (4, 0)
    db3 = next((tmp_path / "in" / "a" / "r2").glob("*.db3"))
    os.utime(db3, ns=(db3.stat().st_atime_ns, db3.stat().st_mtime_ns + 10**9))
    third = clean(str(tmp_path / "in"), str(out), config)
    assert (third.already_done, third.done) == (3, 1) and _records(out)["a/r2"]["status"] == "done"


def test_a_ros2_bag_folder_as_input(tmp_path):
    bag = write_ros2(
        tmp_path / "take1", {"/depth": (frames(), "16UC1"), "/ir": (frames(seed=2), "mono16")}
    )
    report = clean(str(bag), str(tmp_path / "out"), CleanConfig())
    assert report.done == 1 and (tmp_path / "out" / "take1.npz").is_file()


def test_nothing_to_clean_is_an_error_naming_what_was_found(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    status, stdout, err = _cli(["clean", tmp_path / "empty", tmp_path / "o1"], capsys)
    assert status == 2 and stdout == "" and len(err) == 1
    assert "holds no frame file: it is empty; accepted: <name>.npz" in err[0]
    assert (
        err[0].startswith("tof-fpn clean: error: INPUT") and ".mkv" in err[0] and ".bag" in err[0]
    )
    junk = tmp_path / "junk"
    (junk / "sub").mkdir(parents=True)
    for name in ("README.md", "notes.md", "sub/p0tables_3x424x512_u16le.dat", "sub/x.bin"):
        (junk / name).write_bytes(b"123")
    status, _, err = _cli(["clean", junk, tmp_path / "o2"], capsys)
    assert status == 2 and len(err) == 1
    assert "holds no frame file: it holds 4 file(s) (1 .bin, 1 .dat, 2 .md); accepted:" in err[0]
    with pytest.raises(ValueError, match="holds no frame file: it holds 4 file"):
        clean(str(junk), str(tmp_path / "o3"))
    assert not any((tmp_path / o).exists() for o in ("o1", "o2", "o3"))  # nothing written


def test_shared_output_names_and_missing_vendor_partners_fail_alone(tmp_path, capsys):
    src = tmp_path / "in"
    write_ros1(src / "take.bag", {"/depth": (frames(), "16UC1"), "/ir": (frames(seed=2), "16UC1")})
    tio.write_npz(src / "take.npz", np.full((4, 5), 1.0, np.float32), np.ones((4, 5), np.float32))
    frames((1, 4, 6)).astype("<u2").tofile(src / "lone_depth_u16le_4x6.bin")
    status, _, err = _cli(["clean", src, tmp_path / "out", "--quiet"], capsys)
    assert status == 1 and "2 of 3 file(s) failed" in err[-1]
    recs = _records(tmp_path / "out")
    assert recs["take.npz"]["status"] == "done"
    assert "its output take.npz is also the output of ['take.npz']" in recs["take.bag"]["error"]
    assert recs["lone_depth_u16le_4x6.bin"]["error"] == (
        "no partner: lone_ir_u16le_4x6.bin is missing (ADI pairs are "
        "<name>_depth_u16le_<H>x<W>.bin + <name>_ir_u16le_<H>x<W>.bin)"
    )


def test_kinect_raw_pairs_keep_their_height_and_width_beside_vendor_files(tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    frames((1, 4, 5)).astype("<u2").tofile(src / "k_depth.raw")  # Kinect-class: 4 x 5 by flag
    frames((1, 4, 5), seed=1).astype("<u2").tofile(src / "k_amplitude.raw")
    frames((1, 2, 3)).astype("<u2").tofile(src / "w_depth_u16le_2x3.bin")  # 2 x 3 by its name
    frames((1, 2, 3), seed=1).astype("<u2").tofile(src / "w_ir_u16le_2x3.bin")
    status, stdout, err = _cli(
        ["clean", src, tmp_path / "out", "--height", "4", "--width", "5", "--quiet"], capsys
    )
    assert status == 0 and "cleaned 2 file(s) (2 frames)" in stdout, err
    out = tmp_path / "out"
    for name in ("k_amplitude.raw", "w_ir_u16le_2x3.bin"):
        assert (out / name).read_bytes() == (src / name).read_bytes()
    assert (out / "k_depth.raw").stat().st_size == 4 * 5 * 2
    assert (out / "w_depth_u16le_2x3.bin").stat().st_size == 2 * 3 * 2
