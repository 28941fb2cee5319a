"""Small ROS bags written with rosbags' own writers and serializers, for the bag reader and
``tof-fpn clean`` / ``convert`` tests: a generic ROS 1 bag, a ROS 2 bag (sqlite3 or MCAP) and a
bag shaped like a librealsense recording (its topics, its ``Depth Units`` option and the float32
depth unit librealsense >= 2.45 appends to every image message)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

ROS1 = get_typestore(Stores.ROS1_NOETIC)
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
IMAGE = "sensor_msgs/msg/Image"
T0 = 1_700_000_000_123_456_789  # ns: a stamp with every digit used
PERIOD = 33_333_333


def stamps(n: int) -> list[int]:
    return [T0 + i * PERIOD for i in range(n)]


def image(ts, arr: np.ndarray, encoding: str, stamp: int, *, big=False, pad=0, frame_id="cam"):
    """A sensor_msgs/Image of ``arr`` (H, W); ``pad`` bytes of row padding (``step``)."""
    types = ts.types
    header = {
        "stamp": types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    }
    header["frame_id"] = frame_id
    if "seq" in types["std_msgs/msg/Header"].__dataclass_fields__:
        header["seq"] = 7
    rows = arr.astype(arr.dtype.newbyteorder(">" if big else "<")).view(np.uint8)
    rows = np.concatenate([rows, np.full((arr.shape[0], pad), 0xAB, np.uint8)], axis=1)
    return types[IMAGE](
        header=types["std_msgs/msg/Header"](**header),
        height=arr.shape[0],
        width=arr.shape[1],
        encoding=encoding,
        is_bigendian=int(big),
        step=rows.shape[1],
        data=np.ascontiguousarray(rows).reshape(-1),
    )


def write_ros1(
    path, topics: dict[str, tuple[np.ndarray, str]], times=None, compression=None, **kw
) -> Path:
    """A ROS 1 bag: ``topics[name] = (frames (T, H, W), encoding)``, one message per frame at
    ``times[name]`` (default :func:`stamps`), header stamp = record time; ``compression``:
    ``"lz4"`` or ``"bz2"`` chunks (realsense-viewer writes lz4)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = Writer1(path)
    if compression:
        writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    with writer as w:
        for topic, (frames, enc) in topics.items():
            conn = w.add_connection(topic, IMAGE, typestore=ROS1)
            for frame, t in zip(frames, (times or {}).get(topic, stamps(len(frames))), strict=True):
                w.write(conn, t, ROS1.serialize_ros1(image(ROS1, frame, enc, t, **kw), IMAGE))
    return path


def write_ros2(path, topics, storage="sqlite3", times=None, **kw) -> Path:
    """A ROS 2 bag folder (CDR), like :func:`write_ros1`; ``storage``: sqlite3 or mcap."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    with Writer2(path, version=9, storage_plugin=plugin) as w:
        for topic, (frames, enc) in topics.items():
            conn = w.add_connection(topic, IMAGE, typestore=ROS2)
            for frame, t in zip(frames, (times or {}).get(topic, stamps(len(frames))), strict=True):
                w.write(conn, t, ROS2.serialize_cdr(image(ROS2, frame, enc, t, **kw), IMAGE))
    return path


def write_realsense(
    path,
    depth: np.ndarray,
    ir: np.ndarray,
    *,
    units: float = 0.0001,
    per_frame: bool = True,
    option: bool = True,
    infrared=("Infrared_1", "Infrared_2"),
    ir_encoding="8UC1",
) -> Path:
    """A bag laid out like a librealsense recording (file format 3) of a D400-class device:
    sensor 0 holds ``Depth_0`` (mono16) and the infrared streams (Y8 = ``8UC1``), sensor 1 a
    colour stream; ``/device_0/info``, the ``Depth Units`` option (``option``) and, with
    ``per_frame``, librealsense's float32 depth unit after every image's data (its header's
    ``frame_id`` then is ``"1"``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    kv = "diagnostic_msgs/msg/KeyValue"
    with Writer1(path) as w:
        version = w.add_connection("/file_version", "std_msgs/msg/UInt32", typestore=ROS1)
        w.write(
            version,
            1,
            ROS1.serialize_ros1(ROS1.types["std_msgs/msg/UInt32"](data=3), "std_msgs/msg/UInt32"),
        )
        info = w.add_connection("/device_0/info", kv, typestore=ROS1)
        for key, value in (("Name", "Intel RealSense D435"), ("Serial Number", "012345678901")):
            w.write(info, 1, ROS1.serialize_ros1(ROS1.types[kv](key=key, value=value), kv))
        if option:
            f32 = "std_msgs/msg/Float32"
            conn = w.add_connection(
                "/device_0/sensor_0/option/Depth Units/value", f32, typestore=ROS1
            )
            w.write(conn, 1, ROS1.serialize_ros1(ROS1.types[f32](data=units), f32))
        d_conn = w.add_connection("/device_0/sensor_0/Depth_0/image/data", IMAGE, typestore=ROS1)
        meta = w.add_connection("/device_0/sensor_0/Depth_0/image/metadata", kv, typestore=ROS1)
        ir_conns = [
            w.add_connection(f"/device_0/sensor_0/{name}/image/data", IMAGE, typestore=ROS1)
            for name in infrared
        ]
        color = w.add_connection("/device_0/sensor_1/Color_0/image/data", IMAGE, typestore=ROS1)
        frame_id = "1" if per_frame else "0"
        tail = struct.pack("<f", units) if per_frame else b""
        for i, t in enumerate(stamps(len(depth))):
            raw = ROS1.serialize_ros1(image(ROS1, depth[i], "mono16", t, frame_id=frame_id), IMAGE)
            w.write(d_conn, t, bytes(raw) + tail)
            w.write(
                meta, t, ROS1.serialize_ros1(ROS1.types[kv](key="Frame Counter", value=str(i)), kv)
            )
            for k, conn in enumerate(ir_conns):
                frame = ir[i] + k if ir.dtype.kind == "u" else ir[i]
                msg = image(ROS1, frame.astype(ir.dtype), ir_encoding, t, frame_id=frame_id)
                w.write(conn, t, bytes(ROS1.serialize_ros1(msg, IMAGE)) + tail)
            rgb = np.zeros((2, 3), np.uint8)
            w.write(color, t, ROS1.serialize_ros1(image(ROS1, rgb, "rgb8", t), IMAGE))
    return path


def frames(shape=(3, 6, 8), seed=0, lo=0, hi=5000, dtype=np.uint16) -> np.ndarray:
    """Seeded integer frames with some zeros (invalid depth)."""
    rng = np.random.default_rng(seed)
    out = rng.integers(lo, hi, shape).astype(dtype)
    out[:, 0, :2] = 0
    return out
