"""One entry point for every depth / amplitude file of the layer, chosen by the file suffix.

========================  =========================================  ====================
suffix                    holds                                      module
========================  =========================================  ====================
``.npz``                  depth + amplitude (keys ``depth``,          :mod:`.numpy_files`
                          ``amplitude``), a recording too
``.h5``, ``.hdf5``        depth + amplitude datasets                 :mod:`.hdf5`
``.npy``                  depth *or* amplitude                       :mod:`.numpy_files`
``.png``                  depth *or* amplitude (16-bit grey)         :mod:`.images`
``.tif``, ``.tiff``       depth *or* amplitude (grey page / stack)   :mod:`.images`
``.bin``, ``.raw``        depth *or* amplitude (uint16 LE, H x W)    :mod:`.raw`
========================  =========================================  ====================

The reader and the writer of each file are those of its format in the table of formats
(:mod:`.formats`, by suffix: an ADI vendor name is a raw file here). Readers return
``(depth, amplitude)`` float32 (T, 1, H, W): depth in metres with NaN for invalid,
amplitude in camera units; writers take the same (uint16 mm / counts by default).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ._common import check_not_empty, check_same_shape
from .formats import FRAME_SET, PAIR_MEMBER, FileFormat, format_for, suffixes

__all__ = ["PAIR_SUFFIXES", "SINGLE_SUFFIXES", "SUFFIXES", "read_pair", "write_pair"]

#: suffixes of files holding both depth and amplitude
PAIR_SUFFIXES: tuple[str, ...] = suffixes(FRAME_SET)
#: suffixes of files holding one of them
SINGLE_SUFFIXES: tuple[str, ...] = suffixes(PAIR_MEMBER)
SUFFIXES: tuple[str, ...] = PAIR_SUFFIXES + SINGLE_SUFFIXES


def _format(path) -> FileFormat:
    """The frame-file format of ``path``, by its suffix."""
    fmt = format_for(path, by_name=False)
    if fmt is None or fmt.holds not in (FRAME_SET, PAIR_MEMBER):
        s = Path(path).suffix.lower()
        raise ValueError(f"unsupported file suffix {s!r} of {path}; supported: {list(SUFFIXES)}")
    return fmt


def _read_single(path, kind, height, width, depth_scale) -> torch.Tensor:
    fmt = _format(path)
    if fmt.holds == FRAME_SET:
        raise ValueError(f"{path} holds depth and amplitude together; pass it as depth_path alone")
    opts = dict(depth_scale=depth_scale, allow_empty=True) if kind == "depth" else {}
    return fmt.read(path, kind, height=height, width=width, **opts)


def read_pair(
    depth_path,
    amplitude_path=None,
    *,
    height: int | None = None,
    width: int | None = None,
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Read depth and amplitude from one file (``.npz``, ``.h5``) or two files (the others).

    Args:
        depth_path: the file with the depth (or both).
        amplitude_path: the amplitude file; must be None for ``.npz`` / ``.h5``.
        height, width: the frame size of raw ``.bin`` / ``.raw`` files, pixels.
        depth_scale: metres per stored depth unit (default 1 mm for integer, 1 m for floating
            data; HDF5 ``scale_m`` attribute).
        allow_empty: accept frames with no valid pixel (refused by default).

    Returns:
        ``(depth, amplitude)``, float32 (T, 1, H, W): metres with NaN for invalid, camera units.
    """
    fmt = _format(depth_path)
    if fmt.holds == FRAME_SET:
        if amplitude_path is not None:
            raise ValueError(
                f"{depth_path} holds depth and amplitude; amplitude_path must be None, got "
                f"{amplitude_path!r}"
            )
        return fmt.read(depth_path, depth_scale=depth_scale, allow_empty=allow_empty)
    if amplitude_path is None:
        raise ValueError(f"{depth_path} holds depth only; pass amplitude_path too")
    depth = _read_single(depth_path, "depth", height, width, depth_scale)
    amplitude = _read_single(amplitude_path, "amplitude", height, width, None)
    check_same_shape(depth, amplitude, f"{depth_path} / {amplitude_path}")
    check_not_empty(depth, amplitude, f"{depth_path} / {amplitude_path}", allow_empty)
    return depth, amplitude


def write_pair(
    depth_path,
    depth,
    amplitude,
    amplitude_path=None,
    *,
    dtype: str = "uint16",
    amplitude_dtype: str | None = None,
    depth_scale: float | None = None,
) -> tuple[Path, ...]:
    """Write depth (metres, NaN / <= 0 invalid) and amplitude (camera units) to the format of
    the suffix: one file (``.npz``, ``.h5``) or two (``amplitude_path`` for the others).

    ``dtype`` / ``amplitude_dtype``: ``"uint16"`` (mm -- or ``depth_scale`` m -- with 0 invalid;
    rounded counts) or ``"float32"`` (metres with NaN invalid; as given); PNG and raw files are
    uint16 only. Returns the path(s) written."""
    check_same_shape(depth, amplitude, "write_pair")
    fmt = _format(depth_path)
    a_dtype = amplitude_dtype or dtype
    if fmt.holds == FRAME_SET:
        if amplitude_path is not None:
            raise ValueError(f"{depth_path} holds both; amplitude_path must be None")
        kw = dict(dtype=dtype, amplitude_dtype=a_dtype, depth_scale=depth_scale)
        return (fmt.write(depth_path, depth, amplitude, **kw),)
    if amplitude_path is None:
        raise ValueError(f"{depth_path} holds depth only; pass amplitude_path too")
    out = []
    for path, x, kind, dt in (
        (depth_path, depth, "depth", dtype),
        (amplitude_path, amplitude, "amplitude", a_dtype),
    ):
        member = _format(path)
        if member.holds == FRAME_SET:
            raise ValueError(f"{path}: an .npz / .h5 holds both; pass it as depth_path alone")
        scale = {"depth_scale": depth_scale} if kind == "depth" else {}
        out.append(member.write(path, x, kind, dtype=dt, **scale))
    return tuple(out)
