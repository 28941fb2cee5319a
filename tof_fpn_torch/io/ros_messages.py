"""The few ROS messages the bag readers decode, parsed from their serialized bytes.

``sensor_msgs/Image`` in both serializations (ROS 1 and ROS 2's CDR), ``std_msgs/Float32`` and
``diagnostic_msgs/KeyValue`` (ROS 1, as librealsense writes them). They are parsed here rather
than through a type store because (1) a bag need not carry its message definitions (ROS 2
``.db3`` files before Iron do not) and (2) librealsense 2.45 and later append a ``float32``
depth unit after the image data of every frame it records (marked by ``header.frame_id == "1"``,
a field it repurposes as a version), which a strict ROS 1 decoder refuses as a size mismatch.

Encodings read (``sensor_msgs/image_encodings``): ``16UC1`` / ``mono16`` (uint16), ``32FC1``
(float32), ``8UC1`` / ``mono8`` (uint8); ``is_bigendian`` and row padding (``step`` larger than
a row) are honoured. Anything else raises :class:`FormatError`.
"""

from __future__ import annotations

import dataclasses
import struct
from dataclasses import dataclass

import numpy as np

from ._common import FormatError

__all__ = [
    "IMAGE_ENCODINGS",
    "RosImage",
    "image_array",
    "parse_cdr_image",
    "parse_ros1_float32",
    "parse_ros1_image",
    "parse_ros1_key_value",
]

#: encoding -> NumPy dtype of one pixel (single channel)
IMAGE_ENCODINGS: dict[str, str] = {
    "16UC1": "u2",
    "mono16": "u2",
    "32FC1": "f4",
    "8UC1": "u1",
    "mono8": "u1",
}


@dataclass(frozen=True)
class RosImage:
    """A decoded ``sensor_msgs/Image``: the header stamp in ns, the image fields, the pixel bytes
    and, for librealsense recordings, the depth unit stored after them (else None)."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    encoding: str
    is_bigendian: bool
    step: int
    data: bytes
    depth_units: float | None = None


class _Cursor:
    """Reads fields of a serialized message; ``align`` > 1 pads like CDR (offsets from the body)."""

    def __init__(self, buf: memoryview, order: str, cdr: bool, where: str) -> None:
        self.buf, self.order, self.cdr, self.where, self.pos = buf, order, cdr, where, 0

    def _align(self, n: int) -> None:
        if self.cdr:
            self.pos = (self.pos + n - 1) // n * n

    def take(self, fmt: str, size: int):
        self._align(size)
        if self.pos + size > len(self.buf):
            raise FormatError(f"{self.where}: message ends early (truncated or not an Image)")
        value = struct.unpack_from(self.order + fmt, self.buf, self.pos)[0]
        self.pos += size
        return value

    def raw(self, n: int) -> bytes:
        if n < 0 or self.pos + n > len(self.buf):
            raise FormatError(
                f"{self.where}: a field of {n} bytes runs past the message's end "
                f"({len(self.buf)} bytes): truncated or not this message type"
            )
        out = bytes(self.buf[self.pos : self.pos + n])
        self.pos += n
        return out

    def string(self) -> str:
        n = self.take("I", 4)
        text = self.raw(n)
        if self.cdr:  # CDR strings count and store their terminating NUL
            text = text[:-1] if text.endswith(b"\0") else text
        try:
            return text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FormatError(f"{self.where}: a string field is not UTF-8 ({exc})") from exc

    @property
    def left(self) -> int:
        return len(self.buf) - self.pos


def _image_fields(c: _Cursor, stamp_ns: int) -> RosImage:
    frame_id = c.string()
    height, width = c.take("I", 4), c.take("I", 4)
    encoding = c.string()
    is_bigendian = bool(c.take("B", 1))
    step = c.take("I", 4)
    data = c.raw(c.take("I", 4))
    return RosImage(stamp_ns, frame_id, height, width, encoding, is_bigendian, step, data)


def parse_ros1_image(raw, where: str) -> RosImage:
    """A ROS 1 ``sensor_msgs/Image`` (seq, stamp, frame_id, height, width, encoding,
    is_bigendian, step, data), with librealsense's trailing ``float32`` depth unit if present."""
    c = _Cursor(memoryview(raw), "<", cdr=False, where=where)
    c.take("I", 4)  # seq
    sec, nsec = c.take("I", 4), c.take("I", 4)
    img = _image_fields(c, sec * 1_000_000_000 + nsec)
    if c.left == 4 and img.frame_id == "1":  # librealsense >= 2.45: the frame's depth unit
        units = c.take("f", 4)
        return dataclasses.replace(img, depth_units=float(units))
    if c.left:
        raise FormatError(f"{where}: {c.left} byte(s) after the image data (not an Image?)")
    return img


def parse_cdr_image(raw, where: str) -> RosImage:
    """A ROS 2 ``sensor_msgs/msg/Image`` in CDR (little- or big-endian encapsulation)."""
    buf = memoryview(raw)
    if len(buf) < 4 or buf[0] != 0 or buf[1] not in (0, 1):
        raise FormatError(f"{where}: not a CDR message (encapsulation header {bytes(buf[:4])!r})")
    c = _Cursor(buf[4:], "<" if buf[1] == 1 else ">", cdr=True, where=where)
    sec, nsec = c.take("i", 4), c.take("I", 4)
    img = _image_fields(c, sec * 1_000_000_000 + nsec)
    if c.left > 3:  # CDR may pad the end to 4 bytes
        raise FormatError(f"{where}: {c.left} byte(s) after the image data (not an Image?)")
    return img


def parse_ros1_float32(raw, where: str) -> float:
    """A ROS 1 ``std_msgs/Float32``."""
    c = _Cursor(memoryview(raw), "<", cdr=False, where=where)
    value = c.take("f", 4)
    if c.left:
        raise FormatError(f"{where}: expected a std_msgs/Float32 (4 bytes), got {len(raw)} bytes")
    return float(value)


def parse_ros1_key_value(raw, where: str) -> tuple[str, str]:
    """A ROS 1 ``diagnostic_msgs/KeyValue``: ``(key, value)``."""
    c = _Cursor(memoryview(raw), "<", cdr=False, where=where)
    key, value = c.string(), c.string()
    if c.left:
        raise FormatError(f"{where}: {c.left} byte(s) after a diagnostic_msgs/KeyValue")
    return key, value


def image_array(img: RosImage, where: str) -> np.ndarray:
    """The pixels of ``img`` as an (H, W) array of the encoding's dtype, native byte order."""
    code = IMAGE_ENCODINGS.get(img.encoding)
    if code is None:
        raise FormatError(
            f"{where}: image encoding {img.encoding!r}; single-channel {sorted(IMAGE_ENCODINGS)} "
            "are read"
        )
    dt = np.dtype(code).newbyteorder(">" if img.is_bigendian else "<")
    row = img.width * dt.itemsize
    if img.height < 1 or img.width < 1:
        raise FormatError(f"{where}: empty image ({img.height} x {img.width})")
    if img.step < row or len(img.data) < img.step * img.height:
        raise FormatError(
            f"{where}: {len(img.data)} data bytes with step {img.step} do not hold "
            f"{img.height} x {img.width} {img.encoding} pixels"
        )
    rows = np.frombuffer(img.data, np.uint8, img.step * img.height).reshape(img.height, img.step)
    arr = np.ascontiguousarray(rows[:, :row]).view(dt).reshape(img.height, img.width)
    return arr.astype(dt.newbyteorder("="))
