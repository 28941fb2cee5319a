"""ROS bags with a depth and an infrared / amplitude image topic, RealSense recordings among them,
read with ``rosbags`` (pure Python, no ROS installation).

* ROS 1: a ``.bag`` file (``rosbag record``, and librealsense / realsense-viewer recordings);
* ROS 2: a bag folder (``metadata.yaml`` + ``.db3`` / ``.mcap`` files), or one ``.db3`` / ``.mcap``
  storage file; CDR-serialized messages.

**Topics.** Only ``sensor_msgs/Image`` topics are candidates (``CompressedImage`` is not read). The
depth topic is the one whose name has the word ``depth``; the amplitude topic the one with ``ir``,
``infra``, ``infrared``, ``amplitude`` or ``intensity`` (words split at ``/``, ``_``, ``-`` and
``.``, trailing digits ignored, any case). Topics re-projected into another camera (a word
``aligned``, ``registered``, ``rgb``, ``color`` or ``colour``) are taken only when no other
candidate exists; several candidates that differ only in their numbers (``infra1`` /
``infra2``, ``Infrared_1`` / ``Infrared_2``) give the lowest; anything else that leaves several
is an error naming them. ``depth_topic=`` / ``amplitude_topic=`` name them instead.

**Units.** ``16UC1`` / ``mono16`` depth is mm (REP 118), ``32FC1`` depth metres; RealSense
recordings state their depth unit: the value stored after each frame's data (librealsense 2.45
and later), else the first ``/device_<d>/sensor_<s>/option/Depth Units/value`` (``std_msgs/Float32``,
file format 3) or the ``Depth Units`` entry of ``/device_<d>/sensor_<s>/property`` (format 2), else
1 mm; ``depth_scale=`` overrides all of them for integer depth. The float32 unit is taken as the
shortest decimal it stands for (``0.001``, not ``0.0010000000474974513``). Amplitude (``8UC1``,
``mono8``, ``16UC1``, ``mono16``, ``32FC1``) is returned as stored.

**Frames.** Depth and amplitude images are paired by equal ``header.stamp`` (by the bag's record
time when stamps repeat within a topic); unpaired frames are left out and counted in the meta.
``timestamps_s`` count from the first pair, whose time is ``meta["start_time_ns"]``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import torch

from ._common import (
    FormatError,
    amplitude_from_stored,
    check_not_empty,
    check_scale,
    decoding,
    depth_from_stored,
)
from .recording import Recording
from .ros_messages import (
    image_array,
    parse_cdr_image,
    parse_ros1_float32,
    parse_ros1_image,
    parse_ros1_key_value,
)

__all__ = [
    "IMAGE_TYPE",
    "ROS2_METADATA",
    "ROS_BAG_SUFFIXES",
    "choose_topic",
    "is_ros2_bag_dir",
    "read_realsense_bag",
    "read_ros_bag",
    "ros2_bag_files",
    "topic_kind",
]

#: the message type read (rosbags names ROS 1's ``sensor_msgs/Image`` the same way)
IMAGE_TYPE = "sensor_msgs/msg/Image"
#: single-file bags: ROS 1 ``.bag``, ROS 2 storage files
ROS_BAG_SUFFIXES: tuple[str, ...] = (".bag", ".mcap", ".db3")
#: the file that makes a folder a ROS 2 bag
ROS2_METADATA = "metadata.yaml"
_REALSENSE_DEPTH = re.compile(r"^/device_(\d+)/sensor_(\d+)/Depth_\d+/image/data$")
_WORDS = {
    "depth": {"depth"},
    "amplitude": {"ir", "infra", "infrared", "amplitude", "intensity"},
}
_REPROJECTED = {"aligned", "registered", "rgb", "color", "colour"}
_MM = 1e-3


def is_ros2_bag_dir(path) -> bool:
    """A folder holding a rosbag2 ``metadata.yaml`` (its first 64 KiB name
    ``rosbag2_bagfile_information``)."""
    meta = Path(path) / ROS2_METADATA
    try:
        with open(meta, "rb") as fh:
            return b"rosbag2_bagfile_information" in fh.read(1 << 16)
    except OSError:
        return False


def ros2_bag_files(path) -> tuple[str, ...]:
    """The files of a ROS 2 bag folder (``metadata.yaml`` and the storage files), sorted."""
    return tuple(sorted(str(p) for p in Path(path).iterdir() if p.is_file()))


def _import_rosbags():
    try:
        from rosbags import rosbag1, rosbag2
    except ImportError as exc:
        raise ImportError(
            "reading ROS bags needs rosbags (pure Python): pip install rosbags   "
            "(or: pip install 'tof_fpn_torch[bag]')"
        ) from exc
    return rosbag1, rosbag2


def _words(topic: str) -> set[str]:
    return {re.sub(r"\d+$", "", w) for w in re.split(r"[^a-z0-9]+", topic.lower()) if w}


def topic_kind(topic: str) -> str | None:
    """``"depth"``, ``"amplitude"`` or None: what the topic rule (module docstring) takes a topic
    name for."""
    words = _words(topic)
    for kind, names in _WORDS.items():
        if words & names:
            return kind
    return None


def choose_topic(kind: str, topics, given: str | None, where) -> str:
    """The ``kind`` topic among the Image ``topics`` by the rule of the module docstring, or
    ``given`` (which must be one of them). :class:`FormatError` names the candidates."""
    topics = sorted(topics)
    if given is not None:
        if given not in topics:
            raise FormatError(
                f"{where}: no sensor_msgs/Image topic {given!r}; its Image topics: {topics}"
            )
        return given
    found = [t for t in topics if topic_kind(t) == kind]
    if not found:
        raise FormatError(
            f"{where}: no {kind} image topic among the Image topics {topics} (a {kind} topic's "
            f"name has one of the words {sorted(_WORDS[kind])}); name it with {kind}_topic="
        )
    found = [t for t in found if not _words(t) & _REPROJECTED] or found
    if len({re.sub(r"\d+", "#", t) for t in found}) == 1:
        return min(found, key=lambda t: [int(n) for n in re.findall(r"\d+", t)])
    raise FormatError(
        f"{where}: several {kind} image topics {found}; name one with {kind}_topic= "
        f"(tof-fpn convert --{kind}-topic)"
    )


def _decimal(units: float) -> float:
    """A float32 unit as the decimal it stands for (0.001 rather than 0.0010000000474974513)."""
    return float(str(np.float32(units)))


def _realsense(reader, depth_topic: str, where) -> dict:
    """Depth units, their source and the device info of a librealsense recording (ROS 1)."""
    dev, sensor = _REALSENSE_DEPTH.match(depth_topic).groups()
    base = f"/device_{dev}/sensor_{sensor}"
    unit_topics = {f"{base}/option/Depth Units/value", f"{base}/option/Depth_Units/value"}
    wanted = unit_topics | {f"{base}/property", f"/device_{dev}/info"}
    conns = [c for c in reader.connections if c.topic in wanted]
    out = {"units": None, "source": None, "device_info": {}}
    for conn, _, raw in reader.messages(connections=conns) if conns else ():
        at = f"{where} [{conn.topic}]"
        if conn.topic in unit_topics and out["units"] is None:
            out["units"], out["source"] = parse_ros1_float32(raw, at), conn.topic
        elif conn.topic.endswith("/property"):
            key, value = parse_ros1_key_value(raw, at)
            if key == "Depth Units" and out["units"] is None:
                out["units"], out["source"] = float(value), f"{conn.topic} (Depth Units)"
        elif conn.topic.endswith("/info"):
            key, value = parse_ros1_key_value(raw, at)
            out["device_info"][key] = value
    return out


def _pairs(frames: dict[str, list], topics: tuple[str, str], where) -> tuple[list, list, str, int]:
    """Pair the depth and amplitude frames: ``(keys, [(depth item, amplitude item)], key source,
    unpaired counts)``; items are ``(bag time, stamp, array, encoding, depth units, frame_id)``."""
    for index, source in ((1, "header.stamp"), (0, "bag time")):
        keyed = [{item[index]: item for item in frames[t]} for t in topics]
        if all(len(k) == len(frames[t]) for k, t in zip(keyed, topics, strict=True)):
            common = sorted(set(keyed[0]) & set(keyed[1]))
            if not common:
                raise FormatError(
                    f"{where}: no {topics[0]} frame has a {topics[1]} frame of the same "
                    f"{source} ({len(frames[topics[0]])} and {len(frames[topics[1]])} frames)"
                )
            items = [(keyed[0][k], keyed[1][k]) for k in common]
            unpaired = (len(keyed[0]) - len(common), len(keyed[1]) - len(common))
            return common, items, source, unpaired
    raise FormatError(
        f"{where}: frames repeat their header stamp and their record time within a topic; "
        "cannot pair depth and amplitude"
    )


def _read(path, depth_topic, amplitude_topic, depth_scale, allow_empty, realsense_only):
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"ROS bag not found: {p}")
    ros2 = p.is_dir() or p.suffix.lower() in (".mcap", ".db3")
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        raise FormatError(f"{p}: a folder without metadata.yaml is not a ROS 2 bag")
    if p.is_file() and p.suffix.lower() not in ROS_BAG_SUFFIXES:
        raise ValueError(f"{p}: a ROS bag is a {' / '.join(ROS_BAG_SUFFIXES)} file or a folder")
    scale = None if depth_scale is None else check_scale(depth_scale)
    rosbag1, rosbag2 = _import_rosbags()
    frames: dict[str, list] = {}
    rs = None
    with decoding(p, "a ROS 2 bag" if ros2 else "a ROS 1 bag"):
        reader = rosbag2.Reader(p) if ros2 else rosbag1.Reader(p)
        reader.open()
        try:
            images: dict[str, list] = {}
            for c in reader.connections:
                if c.msgtype == IMAGE_TYPE:
                    images.setdefault(c.topic, []).append(c)
            d_topic = choose_topic("depth", images, depth_topic, p)
            if realsense_only and (ros2 or not _REALSENSE_DEPTH.match(d_topic)):
                raise FormatError(
                    f"{p}: no /device_<d>/sensor_<s>/Depth_<i>/image/data topic: not a "
                    f"librealsense recording (Image topics {sorted(images)})"
                )
            a_topic = choose_topic("amplitude", images, amplitude_topic, p)
            if a_topic == d_topic:
                raise FormatError(f"{p}: depth and amplitude must be two topics, got {d_topic!r}")
            conns = images[d_topic] + images[a_topic]
            bad = sorted({c.topic for c in conns if ros2 and _format(c) != "cdr"})
            if bad:
                raise FormatError(f"{p}: topics {bad} are not CDR-serialized (only CDR is read)")
            parse = parse_cdr_image if ros2 else parse_ros1_image
            frames = {d_topic: [], a_topic: []}
            for conn, t, raw in reader.messages(connections=conns):
                img = parse(raw, f"{p} [{conn.topic}]")
                arr = image_array(img, f"{p} [{conn.topic}]")
                frames[conn.topic].append(
                    (t, img.stamp_ns, arr, img.encoding, img.depth_units, img.frame_id)
                )
            if not ros2 and _REALSENSE_DEPTH.match(d_topic):
                rs = _realsense(reader, d_topic, p)
        finally:
            reader.close()
    return _recording(p, ros2, (d_topic, a_topic), frames, rs, scale, allow_empty)


def _format(conn) -> str | None:
    return getattr(conn.ext, "serialization_format", None)


def _recording(p, ros2, topics, frames, rs, scale, allow_empty) -> Recording:
    d_topic, a_topic = topics
    for t in topics:
        if not frames[t]:
            raise FormatError(f"{p}: the topic {t} holds no message")
    keys, items, source, unpaired = _pairs(frames, topics, p)
    for t, i in ((d_topic, 0), (a_topic, 1)):
        encodings = sorted({pair[i][3] for pair in items})
        shapes = sorted({pair[i][2].shape for pair in items})
        if len(encodings) > 1 or len(shapes) > 1:
            raise FormatError(
                f"{p}: the frames of {t} change encoding or size: {encodings} {shapes}"
            )
    d_enc, a_enc = items[0][0][3], items[0][1][3]
    if items[0][0][2].shape != items[0][1][2].shape:
        raise FormatError(
            f"{p}: depth {d_topic} is {items[0][0][2].shape}, amplitude {a_topic} "
            f"{items[0][1][2].shape}; they must have one size (not re-projected)"
        )
    if items[0][0][2].dtype.kind not in "uf" or items[0][0][2].dtype.itemsize == 1:
        raise FormatError(
            f"{p}: depth encoding {d_enc!r}; depth is 16UC1 / mono16 (mm) or 32FC1 (m)"
        )
    floating = items[0][0][2].dtype.kind == "f"
    if floating:
        scales, what = [1.0] * len(items), "32FC1 depth in metres"
    elif scale is not None:
        scales, what = [scale] * len(items), "depth_scale argument"
    else:
        per_frame = [d[4] for d, _ in items]
        if all(u is not None and u > 0 for u in per_frame):
            scales, what = [_decimal(u) for u in per_frame], "the depth unit stored with each frame"
        elif rs is not None and rs["units"] is not None and rs["units"] > 0:
            scales, what = [_decimal(rs["units"])] * len(items), rs["source"]
        else:
            scales, what = [_MM] * len(items), "1 mm (REP 118 default)"
    depth = torch.cat(
        [
            depth_from_stored(d[2][None], None if floating else s)
            for (d, _), s in zip(items, scales, strict=True)
        ]
    )
    amplitude = amplitude_from_stored(np.stack([a[2] for _, a in items]))
    unique_scales = sorted(set(scales))
    kind = "realsense_bag" if rs is not None else ("ros2_bag" if ros2 else "ros1_bag")
    meta = {
        "camera": "realsense" if rs is not None else None,
        "modulation_frequency_hz": None,
        "integration_time_us": None,
        "n_phases": None,
        "amplitude_unit": (
            f"RealSense infrared as recorded ({a_enc})"
            if rs is not None
            else f"the {a_topic} image as stored ({a_enc})"
        ),
        "source": p.name,
        "source_format": kind,
        "depth_topic": d_topic,
        "amplitude_topic": a_topic,
        "depth_encoding": d_enc,
        "amplitude_encoding": a_enc,
        "depth_scale_m": unique_scales[0] if len(unique_scales) == 1 else unique_scales,
        "depth_scale_source": what,
        "frame_id": items[0][0][5],
        "timestamp_source": source,
        "start_time_ns": int(keys[0]),
        "unpaired_depth_frames": unpaired[0],
        "unpaired_amplitude_frames": unpaired[1],
    }
    if rs is not None:
        meta["device_info"] = rs["device_info"]
    ts = np.array([(k - keys[0]) / 1e9 for k in keys], dtype=np.float64)
    rec = Recording(depth, amplitude, meta, timestamps_s=ts)
    check_not_empty(rec.depth, rec.amplitude, str(p), allow_empty)
    return rec


def read_ros_bag(
    path,
    *,
    depth_topic: str | None = None,
    amplitude_topic: str | None = None,
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> Recording:
    """Read the depth and amplitude images of a ROS 1 or ROS 2 bag (RealSense recordings too).

    Args:
        path: a ``.bag`` file, a ROS 2 bag folder (with ``metadata.yaml``) or a ``.db3`` /
            ``.mcap`` file.
        depth_topic, amplitude_topic: the topics to read (default: the topic rule of the module
            docstring).
        depth_scale: metres per stored unit of integer depth (default 1 mm, RealSense: the
            recorded depth unit).
        allow_empty: accept frames with no valid depth (refused by default).

    Returns:
        :class:`~tof_fpn_torch.io.Recording`: depth (T, 1, H, W) metres (0 / NaN invalid), the
        amplitude image as stored, ``timestamps_s`` from the first pair, and meta (``camera``:
        ``"realsense"`` for librealsense recordings, else None; topics, encodings, depth unit
        and its source, pairing, ``device_info`` of a RealSense device).

    Raises:
        ImportError: rosbags is not installed.
        FormatError: not a bag, truncated, no (or several) depth / amplitude Image topics,
            encodings other than the single-channel ones, sizes that differ, no frame pair.
    """
    return _read(path, depth_topic, amplitude_topic, depth_scale, allow_empty, False)


def read_realsense_bag(
    path,
    *,
    depth_topic: str | None = None,
    amplitude_topic: str | None = None,
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> Recording:
    """:func:`read_ros_bag` for a librealsense / realsense-viewer ``.bag``; refuses (with
    :class:`FormatError`) a bag without a ``/device_<d>/sensor_<s>/Depth_<i>/image/data`` topic.
    The amplitude is the infrared stream (``Infrared_<i>``, the lowest index)."""
    return _read(path, depth_topic, amplitude_topic, depth_scale, allow_empty, True)
