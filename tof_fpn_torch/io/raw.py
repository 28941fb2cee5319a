"""Raw frames: headerless little-endian ``uint16``, row-major, of a size the caller states.

Depth is stored in mm (or units of ``depth_scale`` m) with 0 for invalid, amplitude in counts;
a file holds ``T >= 1`` frames back to back, so its size must be ``T * height * width * 2`` bytes.
The reader returns float32 (T, 1, H, W) tensors (depth in metres with NaN for invalid, amplitude in
counts); the writer takes the same and writes the same bytes back (a read-then-write round trip is
byte-exact).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ._common import (
    FormatError,
    amplitude_from_stored,
    amplitude_to_stored,
    as_frames,
    check_kind,
    check_not_empty,
    depth_from_stored,
    depth_to_stored,
    existing_file,
    output_path,
)

__all__ = [
    "RAW_DTYPE",
    "frame_size",
    "raw_write_like",
    "read_raw",
    "read_raw_array",
    "require_frame_size",
    "write_raw",
]

#: the stored sample: little-endian uint16
RAW_DTYPE = np.dtype("<u2")


def frame_size(height, width) -> tuple[int, int]:
    """Check a frame size: two ints >= 1."""
    for name, v in (("height", height), ("width", width)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be an int >= 1 (pixels), got {v!r}")
    return int(height), int(width)


def require_frame_size(path, height, width) -> None:
    """``ValueError`` unless a frame size is given for the raw file ``path`` (its size is not in
    the file)."""
    if height is None or width is None:
        raise ValueError(
            f"raw file {path}: its frame size is not in the file; give height and width "
            "(pixels; tof-fpn: --height / --width)"
        )


def read_raw_array(
    path, height: int, width: int, *, frames: int | None = None, dtype=RAW_DTYPE, what="raw"
) -> np.ndarray:
    """The stored values of a raw file as a (T, H, W) array of ``dtype``.

    ``frames``: the expected frame count (default: the file size decides). A size that is not a
    whole number of frames (a truncated or wrongly sized file) raises :class:`FormatError`."""
    h, w = frame_size(height, width)
    p = existing_file(path, what)
    dtype = np.dtype(dtype)
    nbytes = p.stat().st_size
    per_frame = h * w * dtype.itemsize
    if frames is not None:
        if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
            raise ValueError(f"frames must be an int >= 1 or None, got {frames!r}")
        if nbytes != frames * per_frame:
            raise FormatError(
                f"{p}: {nbytes} bytes, expected {frames} frame(s) of {h} x {w} {dtype} "
                f"= {frames * per_frame} bytes (truncated, or another size)"
            )
    elif nbytes == 0 or nbytes % per_frame:
        raise FormatError(
            f"{p}: {nbytes} bytes is not a whole number of {h} x {w} {dtype} frames "
            f"({per_frame} bytes each): truncated, or another frame size"
        )
    return np.fromfile(p, dtype=dtype).reshape(-1, h, w)


def read_raw(
    path,
    height: int,
    width: int,
    kind: str = "depth",
    *,
    frames: int | None = None,
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> torch.Tensor:
    """Read raw little-endian uint16 frames of depth or amplitude.

    Args:
        path: the file, ``T * height * width * 2`` bytes.
        height, width: the frame size in pixels.
        kind: ``"depth"`` (units of ``depth_scale`` m, default 1 mm; 0 invalid) or
            ``"amplitude"`` (counts).
        frames: the expected number of frames (default: from the file size).
        allow_empty: accept depth frames with no valid pixel (refused by default).

    Returns:
        float32 (T, 1, H, W): depth in metres with NaN for invalid, or amplitude in counts.
    """
    check_kind(kind)
    arr = read_raw_array(path, height, width, frames=frames, what=f"raw {kind}")
    if kind == "amplitude":
        return amplitude_from_stored(arr)
    depth = depth_from_stored(arr, depth_scale)
    check_not_empty(depth, None, str(path), allow_empty)
    return depth


def write_raw(path, x, kind: str = "depth", *, depth_scale: float | None = None) -> Path:
    """Write depth (metres, NaN / <= 0 invalid) or amplitude (camera units) as raw uint16 LE.

    ``x``: (H, W), (T, H, W) or (T, 1, H, W) floating. Depth is stored in units of
    ``depth_scale`` m (default 1 mm) with 0 for invalid; amplitude is rounded to counts."""
    check_kind(kind)
    frames = as_frames(x, kind)
    if kind == "depth":
        arr = depth_to_stored(frames, "uint16", depth_scale)
    else:
        arr = amplitude_to_stored(frames, "uint16")
    p = output_path(path)
    arr.astype(RAW_DTYPE).tofile(p)
    return p


def raw_write_like(dst: Path, arr: np.ndarray) -> None:
    """Write stored values back as raw little-endian uint16 frames."""
    arr.astype(RAW_DTYPE).tofile(dst)
