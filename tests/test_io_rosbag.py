"""The ROS bag reader (tof_fpn_torch.io.rosbag) on bags written by rosbags' own writers: ROS 1,
ROS 2 (sqlite3 and MCAP, folder and single file) and a librealsense-shaped recording, read back
exactly; the topic rule, pairing, units and every refusal."""

from __future__ import annotations

import struct
import sys

import numpy as np
import pytest
import torch
from _bags import (
    PERIOD,
    ROS1,
    ROS2,
    T0,
    frames,
    image,
    stamps,
    write_realsense,
    write_ros1,
    write_ros2,
)

from tof_fpn_torch import io as tio
from tof_fpn_torch.io import FormatError
from tof_fpn_torch.io.ros_messages import image_array, parse_cdr_image, parse_ros1_image
from tof_fpn_torch.io.rosbag import choose_topic, topic_kind

PERIOD_S = PERIOD / 1e9


def _metres(stored: np.ndarray, scale: float) -> torch.Tensor:
    """The reader's contract: float64 product rounded once to float32, NaN where 0."""
    m = torch.from_numpy((stored.astype(np.float64) * scale).astype(np.float32)).unsqueeze(1)
    return torch.where(m > 0, m, torch.full_like(m, float("nan")))


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    return torch.equal(torch.isnan(a), torch.isnan(b)) and torch.equal(
        a.nan_to_num(), b.nan_to_num()
    )


def test_ros1_bag_mm_depth_and_ir_come_back_exactly(tmp_path):
    d, ir = frames(), frames(seed=1, hi=4096)
    bag = write_ros1(
        tmp_path / "r.bag",
        {"/cam/depth/image_raw": (d, "16UC1"), "/cam/ir/image_raw": (ir, "mono16")},
    )
    rec = tio.read_ros_bag(bag)
    assert _same(rec.depth, _metres(d, 1e-3))
    assert torch.equal(rec.amplitude, torch.from_numpy(ir.astype(np.float32)).unsqueeze(1))
    assert rec.timestamps_s.tolist() == pytest.approx([0.0, PERIOD_S, 2 * PERIOD_S], abs=1e-12)
    m = rec.meta
    assert (m["depth_topic"], m["amplitude_topic"], m["source_format"]) == (
        "/cam/depth/image_raw",
        "/cam/ir/image_raw",
        "ros1_bag",
    )
    assert m["camera"] is None and m["depth_scale_m"] == 0.001 and m["start_time_ns"] == T0
    assert (m["unpaired_depth_frames"], m["unpaired_amplitude_frames"]) == (0, 0)
    assert m["timestamp_source"] == "header.stamp" and m["frame_id"] == "cam"
    for compression in ("lz4", "bz2"):  # compressed chunks (realsense-viewer writes lz4)
        topics = {"/cam/depth/image_raw": (d, "16UC1"), "/cam/ir/image_raw": (ir, "mono16")}
        packed = write_ros1(tmp_path / f"{compression}.bag", topics, compression=compression)
        assert packed.stat().st_size < bag.stat().st_size
        again = tio.read_ros_bag(packed)
        assert _same(again.depth, rec.depth) and torch.equal(again.amplitude, rec.amplitude)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros2_bag_metre_depth_big_endian_padded_ir_exactly(tmp_path, storage):
    rng = np.random.default_rng(2)
    d = rng.uniform(0.2, 7.0, (2, 5, 7)).astype(np.float32)
    d[0, 1, 1], d[1, 2, 3], d[1, 0, 0] = np.nan, 0.0, -1.0  # invalid: NaN, 0, negative
    ir = frames((2, 5, 7), seed=3, hi=60000)
    topics = {"/tof/depth": (d, "32FC1"), "/tof/amplitude": (ir, "mono16")}
    bag = write_ros2(tmp_path / "bag2", topics, storage, big=True, pad=3)
    rec = tio.read_ros_bag(bag)
    want = torch.from_numpy(np.where(d > 0, d, np.nan)).unsqueeze(1)
    assert _same(rec.depth, want) and rec.meta["source_format"] == "ros2_bag"
    assert torch.equal(rec.amplitude, torch.from_numpy(ir.astype(np.float32)).unsqueeze(1))
    assert rec.meta["depth_scale_source"] == "32FC1 depth in metres"
    # the storage file alone is a bag too (rosbags reads .db3 / .mcap without metadata.yaml)
    (single,) = [p for p in bag.iterdir() if p.suffix in (".db3", ".mcap")]
    assert _same(tio.read_ros_bag(single).depth, want)


def test_image_parsers_agree_with_rosbags_deserializers():
    rng = np.random.default_rng(4)
    for big, pad, enc, dtype in (
        (False, 0, "16UC1", np.uint16),
        (True, 5, "32FC1", np.float32),
        (False, 1, "mono8", np.uint8),
    ):
        arr = (rng.uniform(0, 200, (3, 4))).astype(dtype)
        for ts, parse, ser, de in (
            (ROS1, parse_ros1_image, ROS1.serialize_ros1, ROS1.deserialize_ros1),
            (ROS2, parse_cdr_image, ROS2.serialize_cdr, ROS2.deserialize_cdr),
        ):
            raw = ser(
                image(ts, arr, enc, T0 + 5, big=big, pad=pad, frame_id="f"), "sensor_msgs/msg/Image"
            )
            ours, ref = parse(raw, "x"), de(raw, "sensor_msgs/msg/Image")
            assert (ours.height, ours.width, ours.step, ours.encoding) == (
                ref.height,
                ref.width,
                ref.step,
                ref.encoding,
            )
            assert ours.data == bytes(ref.data) and ours.stamp_ns == T0 + 5 and ours.frame_id == "f"
            assert np.array_equal(image_array(ours, "x"), arr)


def test_topic_rule_prefers_the_sensor_geometry_and_the_lowest_number():
    assert [
        topic_kind(t)
        for t in (
            "/a/depth/image_raw",
            "/camera/infra1/x",
            "/IR/img",
            "/tof/Intensity",
            "/rgb/image",
        )
    ] == [
        "depth",
        "amplitude",
        "amplitude",
        "amplitude",
        None,
    ]
    topics = [
        "/camera/aligned_depth_to_color/image_raw",
        "/camera/depth/image_rect_raw",
        "/camera/infra2/image",
        "/camera/infra1/image",
        "/camera/color/image_raw",
    ]
    assert choose_topic("depth", topics, None, "b") == "/camera/depth/image_rect_raw"
    assert choose_topic("amplitude", topics, None, "b") == "/camera/infra1/image"
    assert (
        choose_topic("depth", ["/depth_to_rgb/image_raw"], None, "b") == "/depth_to_rgb/image_raw"
    )
    with pytest.raises(
        FormatError, match=r"several depth image topics \['/a/depth', '/b/depth'\].*depth_topic="
    ):
        choose_topic("depth", ["/a/depth", "/b/depth"], None, "b")
    assert choose_topic("depth", ["/a/depth", "/b/depth"], "/b/depth", "b") == "/b/depth"
    with pytest.raises(FormatError, match=r"no sensor_msgs/Image topic '/c'"):
        choose_topic("depth", ["/a/depth"], "/c", "b")


def test_topics_named_by_the_caller_and_refusals(tmp_path):
    d, ir = frames(), frames(seed=1)
    bag = write_ros1(
        tmp_path / "r.bag",
        {"/x/range": (d, "16UC1"), "/x/signal": (ir, "16UC1"), "/x/depth": (d, "16UC1")},
    )
    with pytest.raises(
        FormatError, match=r"r\.bag: no amplitude image topic among .*amplitude_topic="
    ):
        tio.read_ros_bag(bag)
    rec = tio.read_ros_bag(
        bag, depth_topic="/x/range", amplitude_topic="/x/signal", depth_scale=0.0005
    )
    assert (
        _same(rec.depth, _metres(d, 0.0005))
        and rec.meta["depth_scale_source"] == "depth_scale argument"
    )
    with pytest.raises(FormatError, match="two topics"):
        tio.read_ros_bag(bag, depth_topic="/x/range", amplitude_topic="/x/range")


def test_frames_are_paired_by_header_stamp_and_unpaired_ones_counted(tmp_path):
    d, ir = frames((4, 6, 8)), frames((3, 6, 8), seed=1)
    times = {"/depth": stamps(4), "/ir": stamps(4)[1:]}  # the first depth frame has no IR frame
    rec = tio.read_ros_bag(
        write_ros1(tmp_path / "r.bag", {"/depth": (d, "16UC1"), "/ir": (ir, "16UC1")}, times)
    )
    assert rec.frames == 3 and _same(rec.depth, _metres(d[1:], 1e-3))
    assert rec.meta["unpaired_depth_frames"] == 1 and rec.meta["start_time_ns"] == stamps(4)[1]
    times = {"/depth": stamps(2), "/ir": [t + 1 for t in stamps(2)]}
    bag = write_ros1(
        tmp_path / "none.bag", {"/depth": (d[:2], "16UC1"), "/ir": (ir[:2], "16UC1")}, times
    )
    with pytest.raises(
        FormatError, match=r"none\.bag: no /depth frame has a /ir frame of the same header\.stamp"
    ):
        tio.read_ros_bag(bag)


@pytest.mark.parametrize(
    ("topics", "needle"),
    [
        ({"/depth": ("u8", "mono8"), "/ir": ("u16", "mono16")}, "depth encoding 'mono8'"),
        ({"/depth": ("u16", "16UC1"), "/ir": ("rgb", "rgb8")}, "image encoding 'rgb8'"),
        ({"/depth": ("u16", "16UC1"), "/ir": ("small", "16UC1")}, "they must have one size"),
    ],
)
def test_bad_images_are_refused_naming_the_file(tmp_path, topics, needle):
    arrays = {"u8": frames(dtype=np.uint8, hi=200), "u16": frames(), "small": frames((3, 4, 8))}
    arrays["rgb"] = np.zeros((3, 6, 24), np.uint8)  # 8 pixels x 3 channels, as bytes
    bag = write_ros1(tmp_path / "b.bag", {t: (arrays[k], enc) for t, (k, enc) in topics.items()})
    with pytest.raises(FormatError, match=rf"b\.bag.*{needle}"):
        tio.read_ros_bag(bag)


def test_truncated_garbage_and_missing_bags(tmp_path, monkeypatch):
    bag = write_ros1(
        tmp_path / "r.bag", {"/depth": (frames(), "16UC1"), "/ir": (frames(), "16UC1")}
    )
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(FormatError, match=r"cannot read .*cut\.bag as a ROS 1 bag"):
        tio.read_ros_bag(cut)
    (tmp_path / "junk.bag").write_bytes(b"not a bag at all")
    with pytest.raises(FormatError, match=r"junk\.bag as a ROS 1 bag"):
        tio.read_ros_bag(tmp_path / "junk.bag")
    (tmp_path / "nometa").mkdir()
    with pytest.raises(FormatError, match="without metadata.yaml"):
        tio.read_ros_bag(tmp_path / "nometa")
    with pytest.raises(FileNotFoundError, match="absent.bag"):
        tio.read_ros_bag(tmp_path / "absent.bag")
    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(ImportError, match=r"pip install rosbags.*tof_fpn_torch\[bag\]"):
        tio.read_ros_bag(bag)


def test_realsense_recording_with_per_frame_depth_units(tmp_path):
    d, ir = frames(hi=60000), frames(seed=5, hi=250, dtype=np.uint8)
    bag = write_realsense(tmp_path / "rs.bag", d, ir, units=0.0001)
    # the reason for our own parser: rosbags' strict ROS 1 decoder refuses the appended unit
    from rosbags.rosbag1 import Reader

    with Reader(bag) as r:
        conn = next(c for c in r.connections if c.topic.endswith("Depth_0/image/data"))
        raw = next(raw for _, _, raw in r.messages([conn]))
    with pytest.raises(Exception, match="size mismatch"):
        ROS1.deserialize_ros1(raw, "sensor_msgs/msg/Image")
    assert struct.unpack("<f", raw[-4:])[0] == np.float32(0.0001)
    for read in (tio.read_realsense_bag, tio.read_ros_bag):
        rec = read(bag)
        assert _same(rec.depth, _metres(d, 0.0001))  # 0.0001 exactly, not float32's 1.0000000e-4
        assert torch.equal(
            rec.amplitude, torch.from_numpy(ir.astype(np.float32)).unsqueeze(1)
        )  # Infrared_1
        m = rec.meta
        assert m["camera"] == "realsense" and m["source_format"] == "realsense_bag"
        assert (
            m["depth_scale_m"] == 0.0001
            and m["depth_scale_source"] == "the depth unit stored with each frame"
        )
        assert m["amplitude_topic"] == "/device_0/sensor_0/Infrared_1/image/data"
        assert m["device_info"] == {"Name": "Intel RealSense D435", "Serial Number": "012345678901"}


def test_realsense_units_from_the_option_topic_else_one_mm(tmp_path):
    d, ir = frames(), frames(seed=5, hi=250, dtype=np.uint8)
    bag = write_realsense(
        tmp_path / "opt.bag", d, ir, units=0.00025, per_frame=False, infrared=("Infrared_0",)
    )
    rec = tio.read_realsense_bag(bag)
    assert _same(rec.depth, _metres(d, 0.00025))
    assert rec.meta["depth_scale_source"] == "/device_0/sensor_0/option/Depth Units/value"
    bag = write_realsense(tmp_path / "none.bag", d, ir, per_frame=False, option=False)
    rec = tio.read_realsense_bag(bag, depth_scale=None)
    assert _same(rec.depth, _metres(d, 1e-3)) and rec.meta["depth_scale_m"] == 0.001
    plain = write_ros1(tmp_path / "plain.bag", {"/depth": (d, "16UC1"), "/ir": (d, "16UC1")})
    with pytest.raises(FormatError, match="not a librealsense recording"):
        tio.read_realsense_bag(plain)
