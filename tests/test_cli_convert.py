"""``tof-fpn convert``: camera files and folders to recordings (``.npz``) or PNG pairs, exactly;
topics named on the command line; one-line errors with exit status 2; nothing overwritten."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch
from _bags import frames, write_ros1
from conftest import handed_over, real_capture

from tof_fpn_torch import io as tio
from tof_fpn_torch.cli import main


def _cli(argv, capsys):
    status = main(["convert", *[str(a) for a in argv]])
    cap = capsys.readouterr()
    return status, cap.out, cap.err.strip().splitlines()


def test_help(capsys):
    status, out, _ = _cli(["--help"], capsys)
    assert status == 0 and "tof-fpn convert" in out
    for option in ("--to {npz,png}", "--depth-topic", "--amplitude-topic", "--height"):
        assert option in out


def test_the_real_mkv_and_adi_files_become_recordings(tmp_path, capsys):
    src = handed_over(tmp_path / "in")  # the three camera formats, the P0 table, the README
    status, out, err = _cli([src, tmp_path / "rec"], capsys)
    assert status == 0 and err == [] and "converted 3 file(s) (3 frames)" in out, (out, err)
    mkv = tio.read_azure_kinect_mkv(real_capture("azure_kinect/desk_recording.mkv"))
    rec = tio.read_recording(tmp_path / "rec" / "azure_kinect" / "desk_recording.npz")
    assert torch.equal(rec.depth.isnan(), mkv.depth.isnan()) and torch.equal(
        rec.depth.nan_to_num(), mkv.depth.nan_to_num()
    )
    assert torch.equal(rec.amplitude, mkv.amplitude) and rec.meta == mkv.meta
    assert torch.equal(rec.timestamps_s, mkv.timestamps_s)
    wall = tio.read_recording(tmp_path / "rec" / "adi_adtf3175" / "wall.npz")
    d, ir = tio.read_adi_depth_ir(
        *(real_capture(f"adi_adtf3175/wall_{k}_u16le_512x512.bin") for k in ("depth", "ir"))
    )
    assert torch.equal(wall.depth.nan_to_num(), d.nan_to_num()) and torch.equal(wall.amplitude, ir)
    assert (
        wall.meta["camera"] == "adtf3175" and wall.meta["source"] == "wall_depth_u16le_512x512.bin"
    )
    office = tio.read_recording(tmp_path / "rec" / "adi_adtf3175" / "office_mode3.npz")
    assert office.meta["camera"] == "adtf3175" and office.depth.shape == (1, 1, 512, 512)
    # nothing is overwritten: a second run fails every input and leaves the files as they were
    before = (tmp_path / "rec" / "adi_adtf3175" / "wall.npz").read_bytes()
    status, _, err = _cli([src, tmp_path / "rec"], capsys)
    assert (
        status == 1
        and len(err) == 3
        and all("exists; convert does not overwrite" in e for e in err)
    )
    assert (tmp_path / "rec" / "adi_adtf3175" / "wall.npz").read_bytes() == before


def test_a_bag_to_png_pairs_one_per_frame(tmp_path, capsys):
    d, ir = frames((3, 6, 8)), frames((3, 6, 8), seed=1, hi=60000)
    write_ros1(tmp_path / "in" / "take.bag", {"/depth": (d, "16UC1"), "/ir": (ir, "mono16")})
    status, out, err = _cli([tmp_path / "in" / "take.bag", tmp_path / "png", "--to", "png"], capsys)
    assert status == 0 and err == [] and "take.bag -> " in out, (out, err)
    names = sorted(p.name for p in (tmp_path / "png").iterdir())
    assert names == [f"take_{i}_{k}.png" for i in range(3) for k in ("amplitude", "depth")]
    for i in range(3):
        raw = np.asarray(
            __import__("PIL.Image").Image.open(tmp_path / "png" / f"take_{i}_depth.png")
        )
        assert raw.dtype == np.uint16 and np.array_equal(raw, d[i])  # mm, 0 invalid: exact
        amp = tio.read_png(tmp_path / "png" / f"take_{i}_amplitude.png", "amplitude")
        assert np.array_equal(amp[0, 0].numpy(), ir[i].astype(np.float32))


def test_topics_are_named_on_the_command_line(tmp_path, capsys):
    d = frames()
    topics = {"/a/depth": (d, "16UC1"), "/b/depth": (d + 1, "16UC1"), "/a/ir": (d, "16UC1")}
    write_ros1(tmp_path / "in" / "two.bag", topics)
    status, out, err = _cli([tmp_path / "in", tmp_path / "o1"], capsys)
    assert status == 1 and "converted 0 file(s)" in out and len(err) == 1
    assert err[0].startswith("tof-fpn convert: error: two.bag: ")
    assert (
        "several depth image topics ['/a/depth', '/b/depth']" in err[0]
        and "--depth-topic" in err[0]
    )
    status, _, err = _cli([tmp_path / "in", tmp_path / "o2", "--depth-topic", "/b/depth"], capsys)
    assert status == 0 and err == []
    rec = tio.read_recording(tmp_path / "o2" / "two.npz")
    assert rec.meta["depth_topic"] == "/b/depth" and rec.meta["amplitude_topic"] == "/a/ir"
    assert np.array_equal(np.rint(rec.depth[:, 0].numpy() * 1000), d + 1)


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["{t}/absent", "{t}/o"], "INPUT '{t}/absent' does not exist"),
        (["{t}/empty", "{t}/o"], "holds no frame file: it is empty; accepted:"),
        (["{t}/empty", "{t}/empty/o"], "is inside INPUT"),
        (["{t}/file.bag", "{t}/file.bag"], "is a file"),
        (["{t}/empty", "{t}/o", "--height", "4"], "--height and --width go together"),
        (["{t}/empty", "{t}/o", "--to", "tiff"], "invalid choice: 'tiff'"),
    ],
)
def test_bad_arguments_are_one_line_errors_with_status_2(tmp_path, capsys, argv, needle):
    (tmp_path / "empty").mkdir()
    (tmp_path / "file.bag").write_bytes(b"x")
    status, out, err = _cli([a.format(t=tmp_path) for a in argv], capsys)
    assert status == 2 and len(err) == 1, err
    assert err[0].startswith("tof-fpn convert: error:") and needle.format(t=tmp_path) in err[0]
    assert not (tmp_path / "o").exists()


def test_a_bad_file_fails_alone(tmp_path, capsys):
    src = tmp_path / "in"
    write_ros1(src / "good.bag", {"/depth": (frames(), "16UC1"), "/ir": (frames(), "16UC1")})
    shutil.copyfile(src / "good.bag", src / "bad.bag")
    with open(src / "bad.bag", "r+b") as fh:
        fh.truncate(200)
    status, out, err = _cli([src, tmp_path / "o"], capsys)
    assert status == 1 and "converted 1 file(s) (3 frames)" in out and len(err) == 1
    assert (
        err[0].startswith("tof-fpn convert: error: bad.bag: cannot read")
        and "as a ROS 1 bag" in err[0]
    )
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["good.npz"]  # no temporary left
