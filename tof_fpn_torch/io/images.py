"""Image files: 16-bit PNG (read with Pillow, written with ``imageio``) and TIFF (``tifffile``),
one file per depth or amplitude.

Units (``tof_fpn_torch.io._common``): integer images hold depth in mm (0 = invalid) and amplitude
in counts; floating TIFFs hold depth in metres (NaN = invalid) and amplitude in camera units.
Readers return float32 (T, 1, H, W) tensors (depth metres with NaN invalid; amplitude in the
file's units); writers take the same.

* PNG: one single-channel frame (T = 1), written as 16-bit grey (uint16). Any integer grey PNG is
  read (8- or 16-bit); colour PNGs are refused.
* TIFF: one page (H, W) or a stack (T, H, W), written as uint16 (mm / counts) or float32
  (metres / units); colour (samples per pixel > 1) and stacks of more than one leading axis are
  refused.

The stored side (what ``tof-fpn clean`` reads and writes back): :func:`decode_png` and
:func:`decode_tiff` are the one decoder of each format, used by the readers too;
:func:`png_write_like` / :func:`tiff_write_like` write a file back as it came with other pixels.
A PNG may state its depth unit in a ``depth_scale_m`` text chunk (:data:`PNG_SCALE_KEY`, written
by ``png_write_like`` when the unit changes), which :func:`decode_png` returns.

Exactness: the pixel values round-trip exactly (uint16 mm -> metres -> uint16 mm). The writers
are deterministic, so a file they wrote is re-written byte for byte; a file from another encoder
comes back with the same pixels but possibly other compression / tags.
"""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
import tifffile
import torch
from PIL import Image, PngImagePlugin

from ._common import (
    FormatError,
    amplitude_from_stored,
    amplitude_to_stored,
    as_frames,
    check_depth_bits,
    check_kind,
    check_not_empty,
    check_scale,
    decoding,
    depth_from_stored,
    depth_to_stored,
    existing_file,
    output_path,
    stored_frames,
)

__all__ = [
    "PNG_SCALE_KEY",
    "decode_png",
    "decode_tiff",
    "png_write_like",
    "read_png",
    "read_tiff",
    "tiff_write_like",
    "write_png",
    "write_tiff",
]

#: the PNG text chunk that records the depth's metres per stored unit (when not 1 mm)
PNG_SCALE_KEY = "depth_scale_m"


def decode_png(path: Path) -> tuple[np.ndarray, float | None]:
    """The stored image of a single-channel integer PNG, (H, W) in its own dtype (uint8 /
    uint16), and the value of its ``depth_scale_m`` text chunk (None where absent).

    :class:`FormatError` for a file that is not a PNG (whatever its name), a colour, palette or
    alpha image, and a text chunk that is not a scale."""
    with decoding(path, "a PNG image"), Image.open(path) as im:
        if im.format != "PNG":
            raise TypeError(f"a {im.format} image, not a PNG")
        text = im.info.get(PNG_SCALE_KEY)
        arr = np.asarray(im.convert("RGBA") if im.mode == "P" else im)  # a palette is colour
    if arr.ndim != 2 or arr.dtype.kind not in "ui":
        raise FormatError(
            f"{path}: expected a single-channel integer (16-bit grey) PNG, got shape {arr.shape} "
            f"dtype {arr.dtype}"
        )
    try:
        scale = None if text is None else check_scale(float(text), PNG_SCALE_KEY)
    except ValueError as exc:
        raise FormatError(f"{path}: text chunk {PNG_SCALE_KEY}={text!r}: {exc}") from None
    return arr, scale


def decode_tiff(path: Path) -> np.ndarray:
    """The stored frames of a grey TIFF, (H, W) or (T, H, W) in its own dtype; colour and more
    than one leading axis raise :class:`FormatError`."""
    with decoding(path, "a TIFF image"), tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        axes = series.axes
        arr = series.asarray()
    if "S" in axes or not axes.endswith("YX") or len(axes) > 3:
        raise FormatError(
            f"{path}: expected grey frames with axes YX or one leading axis (e.g. IYX), got axes "
            f"{axes!r} and shape {arr.shape}"
        )
    return arr


def _to_tensor(arr: np.ndarray, kind: str, where: str, depth_scale, allow_empty) -> torch.Tensor:
    arr = stored_frames(arr, where)
    if kind == "amplitude":
        return amplitude_from_stored(arr)
    depth = depth_from_stored(arr, depth_scale)
    check_not_empty(depth, None, where, allow_empty)
    return depth


def _stored(x, kind: str, dtype: str, depth_scale) -> np.ndarray:
    frames = as_frames(x, kind)
    if kind == "depth":
        return depth_to_stored(frames, dtype, depth_scale)
    return amplitude_to_stored(frames, dtype)


def read_png(
    path, kind: str = "depth", *, depth_scale: float | None = None, allow_empty: bool = False
) -> torch.Tensor:
    """Read a single-channel (16-bit) PNG of depth or amplitude.

    Args:
        path: the PNG.
        kind: ``"depth"`` (stored in units of ``depth_scale`` m, default 1 mm; 0 invalid) or
            ``"amplitude"`` (counts).
        allow_empty: accept a depth frame with no valid pixel (refused by default).

    Returns:
        float32 (1, 1, H, W): depth in metres with NaN for invalid, or amplitude in counts.
    """
    check_kind(kind)
    p = existing_file(path, f"{kind} PNG")
    arr, _ = decode_png(p)  # the depth_scale_m chunk is read by the stored side only
    if kind == "depth":
        check_depth_bits(arr, p, depth_scale)
    return _to_tensor(arr, kind, str(p), depth_scale, allow_empty)


def write_png(path, x, kind: str = "depth", *, depth_scale: float | None = None) -> Path:
    """Write one depth (metres, NaN / <= 0 invalid) or amplitude (counts) frame as a 16-bit PNG.

    ``x``: (H, W), (1, H, W) or (1, 1, H, W) floating. Depth is stored in units of
    ``depth_scale`` m (default 1 mm) with 0 for invalid; amplitude rounded to uint16 counts."""
    check_kind(kind)
    arr = _stored(x, kind, "uint16", depth_scale)
    if arr.shape[0] != 1:
        raise ValueError(
            f"a PNG holds one frame, got {arr.shape[0]} frames of shape {list(arr.shape[1:])}; "
            "write one file per frame or use TIFF / HDF5 / .npz"
        )
    p = output_path(path)
    iio.imwrite(p, arr[0], extension=".png")
    return p


def read_tiff(
    path, kind: str = "depth", *, depth_scale: float | None = None, allow_empty: bool = False
) -> torch.Tensor:
    """Read a grey TIFF page (H, W) or stack (T, H, W) of depth or amplitude.

    Args:
        path: the TIFF; integer (depth in units of ``depth_scale`` m, default 1 mm, 0 invalid;
            amplitude counts) or floating (depth in metres, NaN / <= 0 invalid).
        kind: ``"depth"`` or ``"amplitude"``.
        allow_empty: accept depth frames with no valid pixel (refused by default).

    Returns:
        float32 (T, 1, H, W): depth in metres with NaN for invalid, or amplitude in file units.
    """
    check_kind(kind)
    p = existing_file(path, f"{kind} TIFF")
    arr = decode_tiff(p)
    return _to_tensor(arr, kind, str(p), depth_scale, allow_empty)


def write_tiff(
    path, x, kind: str = "depth", *, dtype: str = "uint16", depth_scale: float | None = None
) -> Path:
    """Write depth (metres) or amplitude (camera units) as a grey TIFF (one page per frame).

    ``x``: (H, W), (T, H, W) or (T, 1, H, W) floating. ``dtype``: ``"uint16"`` (depth in units
    of ``depth_scale`` m, default mm, 0 invalid; amplitude rounded counts) or ``"float32"``
    (depth in metres, NaN invalid; amplitude as given)."""
    check_kind(kind)
    arr = _stored(x, kind, dtype, depth_scale)
    p = output_path(path)
    tifffile.imwrite(p, arr[0] if arr.shape[0] == 1 else arr, photometric="minisblack")
    return p


def png_write_like(src: Path, dst: Path, arr: np.ndarray, depth_scale: float | None = None) -> None:
    """Write ``arr`` as a PNG with the mode and the text chunks of ``src``; ``depth_scale``
    (metres per unit, where it differs from the input's) is recorded as ``depth_scale_m``."""
    with Image.open(src) as im:
        text = {k: v for k, v in im.info.items() if isinstance(k, str) and isinstance(v, str)}
    if depth_scale is not None:
        text[PNG_SCALE_KEY] = repr(float(depth_scale))
    info = PngImagePlugin.PngInfo()
    for k, v in text.items():
        info.add_text(k, v)
    Image.fromarray(arr).save(dst, format="PNG", pnginfo=info if text else None)


def tiff_write_like(src: Path, dst: Path, arr: np.ndarray) -> None:
    """Write ``arr`` as a TIFF with the compression, description and resolution of ``src``."""
    with tifffile.TiffFile(src) as tif:
        page = tif.pages[0]
        kw = {"compression": page.compression if page.compression != 1 else None}
        desc = page.description
        shaped = desc.startswith("{") and '"shape"' in desc
        if desc and not shaped:
            kw.update(description=desc, metadata=None)
        if "XResolution" in page.tags and "YResolution" in page.tags:
            kw["resolution"] = (page.tags["XResolution"].value, page.tags["YResolution"].value)
    tifffile.imwrite(dst, arr, photometric="minisblack", **kw)
