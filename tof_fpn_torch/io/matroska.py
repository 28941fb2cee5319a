"""Azure Kinect DK recordings (Matroska ``.mkv``, as written by the Azure Kinect SDK's k4arecorder)
read with PyAV (the FFmpeg binding; no vendor SDK).

The SDK stores depth and IR as two ``rawvideo`` tracks titled ``DEPTH`` and ``IR`` whose frames
are 16-bit big-endian grey images (codec tag ``b16g``, FFmpeg pixel format ``gray16be``); depth in
mm with 0 for invalid, IR in the sensor's 16-bit counts. FFmpeg's rawvideo decoder turns them into
native uint16 images, which this reader converts like every other file of the layer. The colour
(MJPG) track, the IMU track and the other attachments are not read; the calibration attachment
(``calibration.json``) is returned in the meta. Reading only: there is no writer (the format is
the SDK's; write a recording with :func:`tof_fpn_torch.io.write_recording`).

PyAV is an optional dependency (``pip install 'tof_fpn_torch[mkv]'``); without it the reader
raises ``ImportError`` saying so.
"""

from __future__ import annotations

import json

import numpy as np

from ._common import (
    FormatError,
    amplitude_from_stored,
    check_not_empty,
    decoding,
    depth_from_stored,
    existing_file,
)
from .recording import Recording

__all__ = ["AZURE_KINECT_AMPLITUDE_UNIT", "read_azure_kinect_mkv"]

AZURE_KINECT_AMPLITUDE_UNIT = "Azure Kinect active IR, 16-bit counts"
_PIXEL_FORMATS = ("gray16be", "gray16le")


def _import_av():
    try:
        import av
    except ImportError as exc:
        raise ImportError(
            "reading Azure Kinect .mkv recordings needs PyAV (FFmpeg bindings): "
            "pip install av   (or: pip install 'tof_fpn_torch[mkv]')"
        ) from exc
    return av


def _track(container, title: str, path):
    for s in container.streams.video:
        if s.metadata.get("title") == title or f"K4A_{title}_TRACK" in s.metadata:
            ctx = s.codec_context
            if ctx.name != "rawvideo" or ctx.pix_fmt not in _PIXEL_FORMATS:
                raise FormatError(
                    f"{path}: the {title} track is {ctx.name} / {ctx.pix_fmt}, expected rawvideo "
                    f"16-bit grey ({' or '.join(_PIXEL_FORMATS)})"
                )
            return s
    titles = [s.metadata.get("title") for s in container.streams.video]
    raise FormatError(
        f"{path}: no {title} track (video tracks: {titles}); an Azure Kinect recording with depth "
        "and IR is needed (depth mode other than OFF / PASSIVE_IR)"
    )


def _calibration(container) -> object:
    """The SDK's calibration JSON (an attachment), or None where it is absent or unreadable
    (PyAV exposes attachment bytes as ``AttachmentStream.data`` in recent versions only)."""
    for s in container.streams:
        if s.type == "attachment" and s.metadata.get("filename") == "calibration.json":
            data = getattr(s, "data", None)
            try:
                return None if data is None else json.loads(bytes(data))
            except (json.JSONDecodeError, UnicodeDecodeError):
                return None
    return None


def read_azure_kinect_mkv(path, *, allow_empty: bool = False) -> Recording:
    """Read the depth and IR frames of an Azure Kinect ``.mkv`` recording.

    Args:
        path: the recording.
        allow_empty: accept frames with no valid depth (refused by default).

    Returns:
        :class:`~tof_fpn_torch.io.Recording`: depth float32 (T, 1, H, W) in metres (stored mm;
        0 -> NaN), amplitude = active IR float32 (T, 1, H, W) in 16-bit counts, timestamps_s
        (T,) the Matroska block times in seconds (the device timestamp adds
        ``meta["start_offset_ns"]``), and meta: ``camera="azure_kinect"``, ``depth_mode``,
        ``ir_mode``, ``k4a_tags`` (the file's K4A tags), ``calibration`` (the SDK's JSON);
        ``modulation_frequency_hz``, ``integration_time_us`` and ``n_phases`` are None (the file
        does not state them).

    Raises:
        ImportError: PyAV is not installed.
        FormatError: not a Matroska file, truncated, no DEPTH / IR track, tracks that are not
            16-bit grey, or a depth frame without the IR frame of the same time.
    """
    av = _import_av()
    p = existing_file(path, "Azure Kinect .mkv")
    with decoding(p, "an Azure Kinect Matroska recording"), av.open(str(p)) as c:
        depth_s, ir_s = _track(c, "DEPTH", p), _track(c, "IR", p)
        d_idx, i_idx = depth_s.index, ir_s.index
        images: dict[int, dict[int, np.ndarray]] = {d_idx: {}, i_idx: {}}
        for packet in c.demux(depth_s, ir_s):
            for frame in packet.decode():
                img = frame.to_ndarray()
                if img.dtype != np.uint16 or img.shape != (frame.height, frame.width):
                    raise FormatError(f"{p}: decoded a {img.dtype} {img.shape} image, not uint16")
                images[packet.stream.index][int(frame.pts)] = img
        time_base = float(depth_s.time_base)
        meta = {
            "camera": "azure_kinect",
            "modulation_frequency_hz": None,
            "integration_time_us": None,
            "n_phases": None,
            "amplitude_unit": AZURE_KINECT_AMPLITUDE_UNIT,
            "source": p.name,
            "depth_mode": depth_s.metadata.get("K4A_DEPTH_MODE"),
            "ir_mode": ir_s.metadata.get("K4A_IR_MODE"),
            "start_offset_ns": int(c.metadata.get("K4A_START_OFFSET_NS", 0)),
            "k4a_tags": {k: v for k, v in c.metadata.items() if k.startswith("K4A_")},
            "calibration": _calibration(c),
        }
    depth_frames, ir_frames = images[d_idx], images[i_idx]
    if not depth_frames:
        raise FormatError(f"{p}: the DEPTH track holds no frame")
    unmatched = sorted(set(depth_frames) ^ set(ir_frames))
    if unmatched:
        raise FormatError(
            f"{p}: {len(unmatched)} depth / IR frame(s) without a partner of the same timestamp "
            f"(pts {unmatched[:5]} in units of {time_base:g} s)"
        )
    pts = sorted(depth_frames)
    depth = depth_from_stored(np.stack([depth_frames[t] for t in pts]))
    ir = amplitude_from_stored(np.stack([ir_frames[t] for t in pts]))
    ts = np.asarray(pts, dtype=np.float64) * time_base
    rec = Recording(depth, ir, meta, timestamps_s=ts)
    check_not_empty(rec.depth, rec.amplitude, str(p), allow_empty)
    return rec
