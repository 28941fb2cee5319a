"""NumPy files: ``.npy`` (one array: depth or amplitude) and ``.npz`` (a depth / amplitude pair).

Units (``tof_fpn_torch.io._common``): integer arrays hold depth in mm (0 = invalid) and amplitude
in counts; floating arrays hold depth in metres (NaN = invalid) and amplitude in camera units.
Readers return float32 (T, 1, H, W) tensors (metres, NaN invalid / camera units); writers take the
same and store ``dtype="uint16"`` (mm, 0 invalid; counts) or ``"float32"`` (metres, NaN invalid).
A single frame is stored as (H, W), several as (T, H, W).

Exactness: a uint16 ``.npy`` read and written back is the same file byte for byte (``np.save``'s
layout). ``.npz`` files are zip archives: the arrays come back exactly, and :func:`save_npz` is
deterministic (fixed zip timestamps), so a file it wrote is re-written byte for byte; an archive
from ``np.savez`` (whose zip entries carry the time of writing) is re-written with other bytes.
Pickled (object) arrays are refused (``allow_pickle=False``).

The stored side (what ``tof-fpn clean`` reads and writes back): :func:`decode_npy` and
:func:`npz_frame_sets` decode a file into its stored arrays (the readers above use the same
decoding), :func:`npy_write_like` / :func:`npz_write_like` write a file back as it came with
another depth.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import torch

from ._common import (
    FormatError,
    FrameSet,
    amplitude_from_stored,
    amplitude_to_stored,
    as_frames,
    check_kind,
    check_not_empty,
    check_same_shape,
    decoding,
    depth_from_stored,
    depth_to_stored,
    existing_file,
    output_path,
    stored_frames,
    stored_scale,
)

__all__ = [
    "decode_npy",
    "load_npz",
    "npy_write_like",
    "npz_frame_sets",
    "npz_write_like",
    "read_npy",
    "read_npz",
    "save_npz",
    "write_npy",
    "write_npz",
]

_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)  # the earliest zip date: a fixed timestamp for every entry


def _squeeze_single(arr: np.ndarray) -> np.ndarray:
    return arr[0] if arr.shape[0] == 1 else arr


def save_npz(path, arrays: dict[str, np.ndarray], compress: bool = False) -> Path:
    """Write ``arrays`` as an ``.npz`` archive, deterministically (fixed zip timestamps).

    ``np.load`` reads it like an ``np.savez`` file. ``compress``: deflate the entries."""
    p = output_path(path)
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(p, "w", compression=method, allowZip64=True) as zf:
        for key, arr in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=_ZIP_EPOCH)
            info.compress_type = method
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)
    return p


def load_npz(path, what: str = "an .npz archive") -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` archive (no pickles); :class:`FormatError` if it is corrupt."""
    p = existing_file(path, what)
    with decoding(p, what):
        f = np.load(p, allow_pickle=False)
        if not isinstance(f, np.lib.npyio.NpzFile):
            raise TypeError("an .npy file, not an .npz archive")
        with f:
            return {k: f[k] for k in f.files}


def decode_npy(path: Path) -> np.ndarray:
    """The one array of an ``.npy`` file as stored (no pickles); :class:`FormatError` if it
    cannot be decoded."""
    with decoding(path, "an .npy array"):
        arr = np.load(path, allow_pickle=False)
        if not isinstance(arr, np.ndarray):
            raise TypeError("an .npz archive, not an .npy array")
    return arr


def _npz_pair(path, depth_key: str, amplitude_key: str):
    """``(depth, amplitude, arrays)``: the two stored (T, H, W) arrays of a depth / amplitude
    archive and all its arrays."""
    arrays = load_npz(path, "a depth / amplitude .npz")
    missing = [k for k in (depth_key, amplitude_key) if k not in arrays]
    if missing:
        raise FormatError(
            f"{path}: no array(s) {missing} in the archive; it holds {sorted(arrays)}"
        )
    d = stored_frames(arrays[depth_key], f"{path} [{depth_key}]")
    a = stored_frames(arrays[amplitude_key], f"{path} [{amplitude_key}]")
    return d, a, arrays


def _recording_camera(arrays: dict) -> str | None:
    """``meta["camera"]`` of a recording ``.npz`` (:mod:`.recording`), else None."""
    try:
        meta = json.loads(str(arrays["meta"].item())) if "content" in arrays else None
    except (KeyError, ValueError):
        return None
    camera = meta.get("camera") if isinstance(meta, dict) else None
    return camera if isinstance(camera, str) else None


def npz_frame_sets(path, depth_scale: float | None = None) -> list[FrameSet]:
    """The stored ``depth`` / ``amplitude`` of an archive as one :class:`FrameSet` (``camera``:
    a recording's ``meta["camera"]``)."""
    d, a, arrays = _npz_pair(path, "depth", "amplitude")
    shape = tuple(arrays["depth"].shape)
    return [FrameSet("", d, a, stored_scale(d, depth_scale), shape, _recording_camera(arrays))]


def npz_write_like(src: Path, dst: Path, arr: np.ndarray) -> None:
    """Copy every entry of the archive ``src`` (name, date, compression, zip64 or not) to
    ``dst``, the content of ``depth.npy`` replaced by ``arr``."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w", allowZip64=True) as zout:
        for old in zin.infolist():
            info = zipfile.ZipInfo(old.filename, date_time=old.date_time)
            info.compress_type = old.compress_type
            info.external_attr = old.external_attr
            zip64 = old.extract_version >= zipfile.ZIP64_VERSION  # written with zip64 headers
            with zout.open(info, "w", force_zip64=zip64) as fh:
                if old.filename == "depth.npy":
                    np.lib.format.write_array(fh, arr, allow_pickle=False)
                else:
                    fh.write(zin.read(old))


def npy_write_like(dst: Path, arr: np.ndarray) -> None:
    """Write ``arr`` as an ``.npy`` in its dtype and shape."""
    with open(dst, "wb") as fh:
        np.lib.format.write_array(fh, arr, allow_pickle=False)


def read_npy(
    path, kind: str = "depth", *, depth_scale: float | None = None, allow_empty: bool = False
) -> torch.Tensor:
    """Read one ``.npy`` array of depth or amplitude frames.

    Args:
        path: the file; (H, W) or (T, H, W), integer or floating dtype.
        kind: ``"depth"`` or ``"amplitude"``.
        depth_scale: metres per stored unit (default 0.001 for integer, 1 for floating arrays).
        allow_empty: accept depth frames with no valid pixel (refused by default).

    Returns:
        float32 (T, 1, H, W): depth in metres with NaN for invalid, or amplitude in the file's
        units.
    """
    check_kind(kind)
    p = existing_file(path, f"{kind} .npy")
    arr = stored_frames(decode_npy(p), str(p))
    if kind == "amplitude":
        return amplitude_from_stored(arr)
    depth = depth_from_stored(arr, depth_scale)
    check_not_empty(depth, None, str(p), allow_empty)
    return depth


def write_npy(
    path, x, kind: str = "depth", *, dtype: str = "uint16", depth_scale: float | None = None
) -> Path:
    """Write depth (metres, NaN / <= 0 invalid) or amplitude (camera units) as one ``.npy``.

    ``x``: (H, W), (T, H, W) or (T, 1, H, W) floating tensor / array. ``dtype``: ``"uint16"``
    (depth in units of ``depth_scale`` m, default mm, 0 invalid; amplitude rounded counts) or
    ``"float32"`` (depth in metres, NaN invalid; amplitude as given)."""
    check_kind(kind)
    frames = as_frames(x, kind)
    if kind == "depth":
        arr = depth_to_stored(frames, dtype, depth_scale)
    else:
        arr = amplitude_to_stored(frames, dtype)
    p = output_path(path)
    np.save(p, _squeeze_single(arr), allow_pickle=False)
    return p


def read_npz(
    path,
    *,
    depth_key: str = "depth",
    amplitude_key: str = "amplitude",
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Read a depth / amplitude pair from one ``.npz`` archive (keys ``depth``, ``amplitude``).

    A recording (:func:`tof_fpn_torch.io.read_recording`) is such an archive too.

    Returns:
        ``(depth, amplitude)``, float32 (T, 1, H, W): metres with NaN for invalid (integer arrays
        count ``depth_scale`` m, default 1 mm; floating ones metres), and camera units.
    """
    d, a, _ = _npz_pair(path, depth_key, amplitude_key)
    check_same_shape(d, a, str(path))
    depth, amplitude = depth_from_stored(d, depth_scale), amplitude_from_stored(a)
    check_not_empty(depth, amplitude, str(path), allow_empty)
    return depth, amplitude


def write_npz(
    path,
    depth,
    amplitude,
    *,
    dtype: str = "uint16",
    amplitude_dtype: str | None = None,
    depth_scale: float | None = None,
    compress: bool = False,
) -> Path:
    """Write a depth / amplitude pair as one ``.npz`` (keys ``depth``, ``amplitude``).

    Args:
        depth: (H, W), (T, H, W) or (T, 1, H, W) floating, metres (NaN / <= 0 invalid).
        amplitude: the same shape, camera units.
        dtype: ``"uint16"`` (depth in mm -- or ``depth_scale`` m -- with 0 invalid) or
            ``"float32"`` (metres, NaN invalid).
        amplitude_dtype: the amplitude's (default ``dtype``): ``"uint16"`` rounds to counts.
        compress: deflate the archive.
    """
    d, a = as_frames(depth, "depth"), as_frames(amplitude, "amplitude")
    check_same_shape(d, a, "write_npz")
    arrays = {
        "depth": _squeeze_single(depth_to_stored(d, dtype, depth_scale)),
        "amplitude": _squeeze_single(amplitude_to_stored(a, amplitude_dtype or dtype)),
    }
    return save_npz(path, arrays, compress)
