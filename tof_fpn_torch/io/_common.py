"""Shared conversions of the file layer: stored arrays <-> the package's tensors, with units.

The package's side is always a float32 CPU tensor of shape (B, 1, H, W): depth in **metres** with
NaN for every invalid pixel (:func:`tof_fpn_torch.runtime.valid_mask`: depth finite and > 0),
amplitude in the **camera's own units** (counts, DN, IR grey levels; never rescaled). The file's
side is a NumPy array of shape (H, W) or (T, H, W) in the file's own dtype and unit:

* integer depth (uint16 and the other integer dtypes) counts ``depth_scale`` metres per unit,
  1 mm (``depth_scale = 0.001``) unless stated otherwise, with 0 (and any value <= 0) invalid;
* floating depth counts ``depth_scale`` metres per unit, 1 m unless stated otherwise, with
  NaN, +-inf and values <= 0 invalid;
* amplitude is stored as it is (uint16 counts or float32).

Every check raises :class:`ValueError` (or its subclass :class:`FormatError` for a file that cannot
be decoded) naming the argument or file, the value found and what is allowed.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..runtime.validity import valid_mask

__all__ = [
    "DEPTH_DTYPES",
    "METRES_PER_MM",
    "UINT16_MAX",
    "FormatError",
    "FrameSet",
    "amplitude_from_stored",
    "amplitude_to_stored",
    "as_frames",
    "check_kind",
    "check_not_empty",
    "check_same_shape",
    "check_scale",
    "decoding",
    "depth_from_stored",
    "depth_to_stored",
    "existing_file",
    "output_path",
    "stored_frames",
    "stored_scale",
]

#: metres per millimetre: the default unit of integer depth files
METRES_PER_MM: float = 1e-3
#: largest value a uint16 file can hold
UINT16_MAX: int = np.iinfo(np.uint16).max
#: the dtypes the writers can store (``"uint16"``: mm / counts; ``"float32"``: metres / units)
DEPTH_DTYPES: tuple[str, ...] = ("uint16", "float32")


class FormatError(ValueError):
    """A file that cannot be decoded as the format it claims (truncated, corrupt, wrong layout,
    wrong dtype). A :class:`ValueError`, so ``except ValueError`` catches it too."""


@dataclass
class FrameSet:
    """Depth and amplitude frames of one file (or one HDF5 group), as stored.

    Attributes:
        key: ``""`` for single-set files; the HDF5 group path (``""`` for the root).
        depth: (T, H, W) stored depth, the file's dtype (units of ``depth_scale`` m).
        amplitude: (T, H, W) stored amplitude, the file's dtype (camera units).
        depth_scale: metres per stored depth unit.
        shape: the stored shape of the depth, (H, W) or (T, H, W), written back as it was.
        camera: the camera profile (:mod:`tof_fpn_torch.cameras`) the file comes from, where
            its format or name tells (``azure_kinect``, ``realsense``, ``adtf3175``, a
            recording's ``meta["camera"]``), else None.
        meta, timestamps_s: a recording container's meta and (T,) timestamps, else None.
    """

    key: str
    depth: np.ndarray
    amplitude: np.ndarray
    depth_scale: float
    shape: tuple[int, ...]
    camera: str | None = None
    meta: dict | None = None
    timestamps_s: np.ndarray | None = None


def stored_scale(arr: np.ndarray, depth_scale) -> float:
    """Metres per stored unit of ``arr``: ``depth_scale`` if given, else 1 mm for integer and
    1 m for floating arrays."""
    if depth_scale is not None:
        return check_scale(depth_scale)
    return METRES_PER_MM if arr.dtype.kind in "ui" else 1.0


def existing_file(path, what: str) -> Path:
    """``path`` as a :class:`~pathlib.Path`; ``FileNotFoundError`` naming ``what`` if absent."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{what} file not found: {p}")
    return p


def output_path(path) -> Path:
    """``path`` as a :class:`~pathlib.Path` whose folder exists (the file may not)."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"path must be a str or os.PathLike, got {type(path).__name__}")
    p = Path(path)
    if not p.parent.is_dir():
        raise FileNotFoundError(f"cannot write {p}: the folder {p.parent} does not exist")
    return p


@contextlib.contextmanager
def decoding(path: Path, what: str):
    """Turn a library's decoding error into a :class:`FormatError` naming the file and format.

    Our own ``ValueError`` s (already clear) and ``FileNotFoundError`` pass through unchanged."""
    try:
        yield
    except (FormatError, FileNotFoundError):
        raise
    except Exception as exc:  # noqa: BLE001 -- any decoder failure: corrupt or truncated file
        raise FormatError(
            f"cannot read {path} as {what}: {type(exc).__name__}: {exc} "
            "(truncated or corrupt file, or not this format)"
        ) from exc


def check_kind(kind: str) -> str:
    if kind not in ("depth", "amplitude"):
        raise ValueError(f"kind must be 'depth' or 'amplitude', got {kind!r}")
    return kind


def _check_dtype_name(dtype: str) -> str:
    if dtype not in DEPTH_DTYPES:
        raise ValueError(f"dtype must be one of {list(DEPTH_DTYPES)}, got {dtype!r}")
    return dtype


def check_scale(depth_scale, name: str = "depth_scale") -> float:
    if isinstance(depth_scale, bool) or not isinstance(depth_scale, (int, float, np.floating)):
        raise ValueError(
            f"{name} must be a real number (metres per stored unit), got {depth_scale!r}"
        )
    s = float(depth_scale)
    if not (np.isfinite(s) and s > 0):
        raise ValueError(f"{name} must be finite and > 0 (metres per stored unit), got {s!r}")
    return s


def stored_frames(arr, where: str) -> np.ndarray:
    """A stored array as (T, H, W): (H, W) -> (1, H, W); integer or floating dtypes only."""
    arr = np.asarray(arr)
    if arr.dtype.kind not in "uif" or arr.dtype.itemsize > 8:
        raise FormatError(
            f"{where}: dtype {arr.dtype} is not a depth / amplitude dtype (an integer or floating "
            "dtype: uint16 mm / counts, float32 metres / units)"
        )
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise FormatError(f"{where}: expected an (H, W) or (T, H, W) array, got shape {arr.shape}")
    if 0 in arr.shape:
        raise FormatError(f"{where}: empty array of shape {arr.shape}")
    return arr


def as_frames(x, name: str) -> np.ndarray:
    """A writer's input as a floating (T, H, W) array: a tensor or array of shape (H, W),
    (T, H, W) or (T, 1, H, W) (the package's (B, 1, H, W))."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    elif not isinstance(x, np.ndarray):
        raise ValueError(f"{name} must be a torch.Tensor or numpy.ndarray, got {type(x).__name__}")
    if x.dtype.kind != "f":
        raise ValueError(
            f"{name} must be floating point (depth in metres, amplitude in camera units), got "
            f"dtype {x.dtype}; integer files are read and written by the readers / writers"
        )
    if x.ndim == 4 and x.shape[1] == 1:
        x = x[:, 0]
    elif x.ndim == 2:
        x = x[None]
    if x.ndim != 3 or 0 in x.shape:
        raise ValueError(
            f"{name} must have shape (H, W), (T, H, W) or (T, 1, H, W) with no empty axis, got "
            f"{list(x.shape)}"
        )
    return x


def check_depth_bits(arr: np.ndarray, where, depth_scale) -> None:
    """Refuse 8-bit integer depth unless its metres per unit are given: 0-255 mm is not a depth
    map (it is a preview or a mask exported as an image)."""
    if arr.dtype.kind in "ui" and arr.dtype.itemsize == 1 and depth_scale is None:
        raise FormatError(
            f"{where}: 8-bit depth holds 0-255 units, not a depth map (depth files are 16-bit "
            "mm); if it really is depth, give its metres per unit (depth_scale, --depth-scale)"
        )


def depth_from_stored(arr: np.ndarray, depth_scale: float | None = None) -> torch.Tensor:
    """Stored depth (T, H, W) -> float32 (T, 1, H, W) metres, NaN wherever the pixel is invalid.

    ``depth_scale``: metres per stored unit; ``None`` is 0.001 (mm) for integer arrays and 1 (m)
    for floating ones. The product is formed in float64 and rounded once to float32, so a uint16
    mm value ``v`` comes back from :func:`depth_to_stored` as ``v`` exactly."""
    if depth_scale is None:
        depth_scale = METRES_PER_MM if arr.dtype.kind in "ui" else 1.0
    scale = check_scale(depth_scale)
    metres = arr.astype(np.float64) * scale if scale != 1.0 else arr.astype(np.float64)
    t = torch.from_numpy(metres.astype(np.float32)).unsqueeze(1)
    return torch.where(valid_mask(t), t, torch.full_like(t, float("nan")))


def amplitude_from_stored(arr: np.ndarray) -> torch.Tensor:
    """Stored amplitude (T, H, W) -> float32 (T, 1, H, W) in the camera's units (unchanged)."""
    return torch.from_numpy(arr.astype(np.float32)).unsqueeze(1)


def depth_to_stored(
    depth: np.ndarray, dtype: str = "uint16", depth_scale: float | None = None
) -> np.ndarray:
    """Depth (T, H, W) metres -> the file's array: ``"uint16"`` counts of ``depth_scale`` m
    (default 1 mm) with 0 for invalid, or ``"float32"`` units of ``depth_scale`` m (default 1 m)
    with NaN for invalid. Invalid is :func:`valid_mask`'s rule (non-finite or <= 0).

    Raises ``ValueError`` where a valid depth does not fit: above ``65535 depth_scale`` m, or
    below half a unit (it would round to 0, the invalid code)."""
    _check_dtype_name(dtype)
    if depth_scale is None:
        depth_scale = METRES_PER_MM if dtype == "uint16" else 1.0
    scale = check_scale(depth_scale)
    d = depth.astype(np.float64)
    valid = valid_mask(torch.from_numpy(d)).numpy()
    units = np.where(valid, d, 0.0) / scale
    if dtype == "float32":
        return np.where(valid, units, np.nan).astype(np.float32)
    counts = np.rint(units)
    if valid.any():
        lo, hi = float(counts[valid].min()), float(counts[valid].max())
        if hi > UINT16_MAX:
            raise ValueError(
                f"depth up to {float(d[valid].max()):g} m does not fit uint16 at {scale:g} m per "
                f"unit (at most {UINT16_MAX * scale:g} m); pass dtype='float32' or a larger "
                "depth_scale"
            )
        if lo < 1:
            raise ValueError(
                f"depth {float(d[valid].min()):g} m rounds to 0 units of {scale:g} m, the uint16 "
                "invalid code; pass dtype='float32' or a smaller depth_scale"
            )
    return counts.astype(np.uint16)


def amplitude_to_stored(amplitude: np.ndarray, dtype: str = "uint16") -> np.ndarray:
    """Amplitude (T, H, W), camera units -> ``"uint16"`` (rounded to the nearest integer; finite,
    in [0, 65535] required: uint16 has no invalid code) or ``"float32"`` (as it is)."""
    _check_dtype_name(dtype)
    if dtype == "float32":
        return amplitude.astype(np.float32)
    a = amplitude.astype(np.float64)
    bad = ~np.isfinite(a)
    if bad.any():
        raise ValueError(
            f"amplitude has {int(bad.sum())} NaN/inf value(s); uint16 files have no invalid code "
            "for amplitude: pass dtype='float32'"
        )
    if a.min() < 0 or np.rint(a.max()) > UINT16_MAX:
        raise ValueError(
            f"amplitude must lie in [0, {UINT16_MAX}] to be stored as uint16, got "
            f"[{a.min():g}, {a.max():g}]; pass dtype='float32'"
        )
    return np.rint(a).astype(np.uint16)


def check_same_shape(depth, amplitude, where: str) -> None:
    """Depth and amplitude frames must have one shape."""
    if tuple(depth.shape) != tuple(amplitude.shape):
        raise ValueError(
            f"{where}: depth and amplitude must have the same shape, got {list(depth.shape)} and "
            f"{list(amplitude.shape)}"
        )


def check_not_empty(
    depth: torch.Tensor, amplitude: torch.Tensor | None, where: str, allow_empty: bool
) -> None:
    """A frame (B index) with no valid pixel (:func:`valid_mask` of depth and amplitude) is
    refused unless ``allow_empty``: it carries no measurement (all NaN / 0)."""
    if allow_empty:
        return
    valid = valid_mask(depth, amplitude)
    empty = (~valid.flatten(1).any(1)).nonzero().flatten().tolist()
    if empty:
        raise ValueError(
            f"{where}: frame(s) {empty[:10]}{' ...' if len(empty) > 10 else ''} of "
            f"{depth.shape[0]} have no valid pixel (depth finite and > 0, amplitude finite and "
            ">= 0)"
        )
