"""Files as stored: read the depth / amplitude arrays in the file's own dtype and write a file back
**as it came**, with only the depth replaced (what ``tof-fpn clean`` needs).

The other readers of this layer return the package's tensors (metres, camera units); here the
stored values and the file's layout are kept, so that a tool can write an output that has the
input's dtype, units, shape, name and metadata:

=================  ===============================================================================
format             kept when :func:`write_like` writes the file back
=================  ===============================================================================
16-bit PNG         mode (8- / 16-bit grey), the text chunks (``tEXt``) before the image data
TIFF               dtype, (H, W) or (T, H, W), compression, the image description, resolution
``.npy``           dtype, (H, W) or (T, H, W)
``.npz``           every other array byte for byte; each entry's name, date and compression
HDF5               the whole file (every other dataset, group and attribute, the depth dataset's
                   dtype, chunks, filters and attributes): it is copied and the depth values
                   are overwritten in place
raw ``.bin``       little-endian uint16, frames back to back
=================  ===============================================================================

A file holds one or more :class:`FrameSet`: one for every format but HDF5, where every group
holding a ``depth`` and an ``amplitude`` dataset (the root included) is one, keyed by its path.
The reader and the writer of a file are those of its format in the table of formats
(:func:`~.formats.format_for`); each format's module decodes and writes it.
:func:`frame_set_tensors` turns a set into the package's tensors (depth metres, NaN invalid;
amplitude camera units) and :func:`~.encode.encode_depth` turns cleaned depth (metres) back into the stored
dtype, leaving the stored value of every invalid input pixel as it was. Decoding errors raise
:class:`FormatError` naming the file. Camera files (an Azure Kinect ``.mkv``, ROS bags, ADI
vendor-named raw files, :mod:`.camera_files`) are formats of the table too.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from ._common import (
    FrameSet,
    amplitude_from_stored,
    check_not_empty,
    check_same_shape,
    depth_from_stored,
    existing_file,
    stored_frames,
)
from .formats import CAMERA_FILE, FRAME_SET, PAIR_MEMBER, RECORDING, format_for, format_of_name
from .images import PNG_SCALE_KEY

__all__ = [
    "PNG_SCALE_KEY",
    "FrameSet",
    "frame_set_tensors",
    "read_frame_sets",
    "write_like",
]


def _member(path: Path, kind: str, height, width, depth_scale=None) -> tuple[np.ndarray, float]:
    """The stored array of one file of a pair and its metres per unit, by the file's suffix."""
    fmt = format_of_name(path.name, by_name=False)
    if fmt is None or fmt.holds != PAIR_MEMBER:
        raise ValueError(f"unsupported suffix {path.suffix.lower()!r} of {path}")
    return fmt.read_stored(path, kind, height=height, width=width, depth_scale=depth_scale)


def read_frame_sets(
    depth_path,
    amplitude_path=None,
    *,
    height: int | None = None,
    width: int | None = None,
    depth_scale: float | None = None,
) -> list[FrameSet]:
    """Read the stored frames of one frame file (the suffixes of :func:`~.pairs.read_pair`) or
    camera file (:mod:`.camera_files`).

    Args:
        depth_path: the depth file, or the ``.npz`` / ``.h5`` / camera file holding both.
        amplitude_path: the amplitude file (None for ``.npz`` / ``.h5`` / containers).
        height, width: frame size of raw ``.bin`` / ``.raw`` files, pixels.
        depth_scale: metres per stored depth unit (default 1 mm for integer data, 1 m for
            floating data, an HDF5 dataset's ``scale_m`` attribute, a PNG's ``depth_scale_m``
            text chunk).

    Returns:
        the file's :class:`FrameSet` s (several for an HDF5 file with several groups). A
        recording container's set is float32 metres with NaN (``depth_scale`` 1) with the
        reader's meta and timestamps; an ADI vendor file's its stored uint16, the size from
        its name (docs/io.md).

    Raises:
        FormatError: a file that cannot be decoded, an array of another dtype or rank.
        ValueError: depth and amplitude of different shapes.
    """
    fmt = format_for(depth_path) if isinstance(depth_path, (str, os.PathLike)) else None
    if fmt is not None and fmt.holds in (RECORDING, CAMERA_FILE):
        return fmt.read_stored(depth_path, amplitude_path, depth_scale=depth_scale)
    p = existing_file(depth_path, "depth")
    if fmt is not None and fmt.holds == FRAME_SET:
        sets = fmt.read_stored(p, amplitude_path, depth_scale=depth_scale)
    else:
        if amplitude_path is None:
            raise ValueError(f"{p} holds depth only; pass amplitude_path too")
        q = existing_file(amplitude_path, "amplitude")
        raw_d, scale = _member(p, "depth", height, width, depth_scale)
        raw_a, _ = _member(q, "amplitude", height, width)
        d, a = stored_frames(raw_d, str(p)), stored_frames(raw_a, str(q))
        check_same_shape(d, a, f"{p} / {q}")
        sets = [FrameSet("", d, a, scale, tuple(raw_d.shape))]
    for fs in sets:
        check_same_shape(fs.depth, fs.amplitude, f"{p}{' [' + fs.key + ']' if fs.key else ''}")
    return sets


def frame_set_tensors(
    fs: FrameSet, where: str = "frame set", allow_empty: bool = False
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(depth, amplitude)``: float32 (T, 1, H, W), depth in metres with NaN for every invalid
    pixel, amplitude in the camera's units. A frame with no valid pixel raises ``ValueError``
    unless ``allow_empty``."""
    depth = depth_from_stored(fs.depth, fs.depth_scale)
    amplitude = amplitude_from_stored(fs.amplitude)
    check_not_empty(depth, amplitude, where, allow_empty)
    return depth, amplitude


def write_like(
    src,
    dst,
    depths: dict[str, np.ndarray],
    sets: list[FrameSet],
    depth_scale: float | None = None,
) -> Path:
    """Write ``dst`` as a copy of the depth file ``src`` with the depth of each frame set
    replaced by ``depths[key]`` ((T, H, W) arrays of the stored dtype, from
    :func:`~.encode.encode_depth`).

    What is kept of each format: the module docstring; a recording container is written as the
    package's recording ``.npz`` (its reader's meta and timestamps, its amplitude), an ADI
    interleaved file with only its depth bytes replaced. ``dst`` must not be ``src``; its folder
    must exist (the caller writes to a temporary name there and renames). ``depth_scale``: the
    metres per unit of ``depths`` where it differs from the input's (``encode_depth``'s
    ``output_scale``): recorded as a PNG's ``depth_scale_m`` text chunk and as an HDF5 depth
    dataset's ``scale_m`` attribute; the other formats have no place for it."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise ValueError(f"write_like: dst must differ from src, got {src} twice")
    by_key = {fs.key: fs for fs in sets}
    if set(depths) != set(by_key):
        raise ValueError(f"write_like: depths for {sorted(depths)}, the file has {sorted(by_key)}")
    arrays = {}
    for key, arr in depths.items():
        fs = by_key[key]
        if arr.dtype != fs.depth.dtype or arr.shape != fs.depth.shape:
            raise ValueError(
                f"write_like: depth {key!r} must be {fs.depth.dtype} {fs.depth.shape}, got "
                f"{arr.dtype} {arr.shape}"
            )
        arrays[key] = np.ascontiguousarray(arr.reshape(fs.shape))
    fmt = format_for(src)
    if fmt is None or fmt.rewriter is None:
        raise ValueError(f"write_like: unsupported suffix {src.suffix.lower()!r} of {src}")
    fmt.write_like(src, dst, arrays, by_key, depth_scale)
    return dst
