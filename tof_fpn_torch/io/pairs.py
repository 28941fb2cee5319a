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

Readers return ``(depth, amplitude)`` float32 (T, 1, H, W): depth in metres with NaN for invalid,
amplitude in camera units; writers take the same (uint16 mm / counts by default).
"""

from __future__ import annotations

from pathlib import Path

import torch

from ._common import check_not_empty, check_same_shape
from .hdf5 import read_hdf5, write_hdf5
from .images import read_png, read_tiff, write_png, write_tiff
from .numpy_files import read_npy, read_npz, write_npy, write_npz
from .raw import read_raw, write_raw

__all__ = ["PAIR_SUFFIXES", "SINGLE_SUFFIXES", "SUFFIXES", "read_pair", "write_pair"]

#: suffixes of files holding both depth and amplitude
PAIR_SUFFIXES: tuple[str, ...] = (".npz", ".h5", ".hdf5")
#: suffixes of files holding one of them
SINGLE_SUFFIXES: tuple[str, ...] = (".npy", ".png", ".tif", ".tiff", ".bin", ".raw")
SUFFIXES: tuple[str, ...] = PAIR_SUFFIXES + SINGLE_SUFFIXES
_RAW = (".bin", ".raw")


def _suffix(path) -> str:
    s = Path(path).suffix.lower()
    if s not in SUFFIXES:
        raise ValueError(f"unsupported file suffix {s!r} of {path}; supported: {list(SUFFIXES)}")
    return s


def _read_single(path, kind, height, width, depth_scale) -> torch.Tensor:
    s = _suffix(path)
    if s in PAIR_SUFFIXES:
        raise ValueError(f"{path} holds depth and amplitude together; pass it as depth_path alone")
    opts = dict(depth_scale=depth_scale, allow_empty=True) if kind == "depth" else {}
    if s in _RAW:
        if height is None or width is None:
            raise ValueError(
                f"raw file {path}: its frame size is not in the file; give height and width "
                "(pixels; tof-fpn: --height / --width)"
            )
        return read_raw(path, height, width, kind, **opts)
    reader = {".npy": read_npy, ".png": read_png, ".tif": read_tiff, ".tiff": read_tiff}[s]
    return reader(path, kind, **opts)


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
    s = _suffix(depth_path)
    if s in PAIR_SUFFIXES:
        if amplitude_path is not None:
            raise ValueError(
                f"{depth_path} holds depth and amplitude; amplitude_path must be None, got "
                f"{amplitude_path!r}"
            )
        reader = read_npz if s == ".npz" else read_hdf5
        return reader(depth_path, depth_scale=depth_scale, allow_empty=allow_empty)
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
    s = _suffix(depth_path)
    a_dtype = amplitude_dtype or dtype
    if s in PAIR_SUFFIXES:
        if amplitude_path is not None:
            raise ValueError(f"{depth_path} holds both; amplitude_path must be None")
        writer = write_npz if s == ".npz" else write_hdf5
        kw = dict(dtype=dtype, amplitude_dtype=a_dtype, depth_scale=depth_scale)
        return (writer(depth_path, depth, amplitude, **kw),)
    if amplitude_path is None:
        raise ValueError(f"{depth_path} holds depth only; pass amplitude_path too")
    out = []
    for path, x, kind, dt in (
        (depth_path, depth, "depth", dtype),
        (amplitude_path, amplitude, "amplitude", a_dtype),
    ):
        t = _suffix(path)
        if t in PAIR_SUFFIXES:
            raise ValueError(f"{path}: an .npz / .h5 holds both; pass it as depth_path alone")
        scale = {"depth_scale": depth_scale} if kind == "depth" else {}
        if t in (".png", *_RAW):
            if dt != "uint16":
                raise ValueError(f"{path}: {t} files are uint16 only, got dtype {dt!r}")
            write = write_png if t == ".png" else write_raw
            out.append(write(path, x, kind, **scale))
        else:
            write = write_npy if t == ".npy" else write_tiff
            out.append(write(path, x, kind, dtype=dt, **scale))
    return tuple(out)
