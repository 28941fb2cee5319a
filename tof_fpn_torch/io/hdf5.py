"""HDF5 files (``h5py``): a depth and an amplitude dataset, (H, W) or (T, H, W), in one file.

Units (``tof_fpn_torch.io._common``): integer datasets hold depth in mm (0 = invalid) and amplitude
in counts; floating ones depth in metres (NaN = invalid) and amplitude in camera units. A depth
dataset may state its unit with the attribute ``scale_m`` (metres per stored unit), which the
reader uses unless ``depth_scale`` is passed; the writer always sets ``scale_m``, ``unit`` and
``invalid`` (``0`` or ``NaN``) on the depth and ``unit`` on the amplitude.

Readers return float32 (T, 1, H, W) tensors (metres with NaN invalid; camera units); writers take
the same. Only integer and floating datasets are read: strings, booleans, complex or compound
dtypes raise :class:`FormatError`, as do missing datasets and groups in their place.

The stored side (what ``tof-fpn clean`` reads and writes back): :func:`hdf5_frame_sets` returns
every group holding a ``depth`` and an ``amplitude`` dataset (the root included) in its stored
dtype, decoded like :func:`read_hdf5` decodes its two datasets; :func:`hdf5_write_like` copies a
file and overwrites its depth datasets in place.

Exactness: values round-trip exactly (uint16 mm -> metres -> uint16 mm); the writer stores no
timestamps (``track_times=False``), so a file it wrote is re-written byte for byte.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import torch

from ._common import (
    METRES_PER_MM,
    FormatError,
    FrameSet,
    amplitude_from_stored,
    amplitude_to_stored,
    as_frames,
    check_not_empty,
    check_same_shape,
    check_scale,
    decoding,
    depth_from_stored,
    depth_to_stored,
    existing_file,
    output_path,
    stored_frames,
    stored_scale,
)

__all__ = ["hdf5_frame_sets", "hdf5_write_like", "read_hdf5", "write_hdf5"]


def _dataset(f: h5py.File, key: str, path: Path) -> h5py.Dataset:
    if key not in f:
        raise FormatError(f"{path}: no dataset {key!r}; the file holds {sorted(f.keys())}")
    ds = f[key]
    if not isinstance(ds, h5py.Dataset):
        raise FormatError(f"{path}: {key!r} is a {type(ds).__name__}, not a dataset")
    if ds.dtype.kind not in "uif":
        raise FormatError(
            f"{path}: dataset {key!r} has dtype {ds.dtype}; depth / amplitude must be integer "
            "(uint16 mm / counts) or floating (float32 metres / units)"
        )
    return ds


def _stored_pair(f: h5py.File, path: Path, depth_key: str, amplitude_key: str, depth_scale):
    """``(depth, amplitude, stored depth shape, depth_scale)`` of two datasets, as stored: the
    one decoder of the format. ``depth_scale`` None: the depth's ``scale_m`` attribute, if any."""
    dset, aset = _dataset(f, depth_key, path), _dataset(f, amplitude_key, path)
    if depth_scale is None and "scale_m" in dset.attrs:
        where = f"{path} [{depth_key}].attrs['scale_m']"
        try:
            depth_scale = check_scale(float(np.asarray(dset.attrs["scale_m"])), where)
        except (TypeError, ValueError) as exc:
            raise FormatError(f"{where}: not a scale in metres per unit: {exc}") from exc
    d, a = dset[()], aset[()]
    shape = tuple(d.shape)
    d = stored_frames(d, f"{path} [{depth_key}]")
    a = stored_frames(a, f"{path} [{amplitude_key}]")
    return d, a, shape, depth_scale


def hdf5_frame_sets(path, depth_scale: float | None = None) -> list[FrameSet]:
    """Every group of the file holding a ``depth`` and an ``amplitude`` dataset (the root
    included) as a :class:`FrameSet` keyed by the group's path, in the stored dtype."""
    found = []
    with decoding(path, "an HDF5 file"), h5py.File(path, "r") as f:
        groups = [("", f)]
        f.visititems(
            lambda name, obj: groups.append((name, obj)) if isinstance(obj, h5py.Group) else None
        )
        for key, g in groups:
            if "depth" in g and "amplitude" in g:
                prefix = f"{key}/" if key else ""
                pair = _stored_pair(f, path, f"{prefix}depth", f"{prefix}amplitude", depth_scale)
                found.append((key, *pair))
    if not found:
        raise FormatError(f"{path}: no group holds both a 'depth' and an 'amplitude' dataset")
    return [FrameSet(k, d, a, stored_scale(d, s), shape) for k, d, a, shape, s in found]


def hdf5_write_like(src: Path, dst: Path, arrays: dict, depth_scale: float | None = None) -> None:
    """Copy ``src`` to ``dst`` and overwrite the depth dataset of each group key of ``arrays``
    in place (every other dataset, group, attribute, chunking and filter kept); ``depth_scale``
    (where the unit changes) is set as the depth's ``scale_m``."""
    shutil.copyfile(src, dst)
    with h5py.File(dst, "r+") as f:
        for key, arr in arrays.items():
            dset = f[f"{key}/depth" if key else "depth"]
            dset[...] = arr
            if depth_scale is not None:
                dset.attrs["scale_m"] = float(depth_scale)


def read_hdf5(
    path,
    *,
    depth_key: str = "depth",
    amplitude_key: str = "amplitude",
    depth_scale: float | None = None,
    allow_empty: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Read a depth / amplitude pair from an HDF5 file.

    Args:
        path: the file.
        depth_key, amplitude_key: dataset paths inside it (``"depth"``, ``"amplitude"``).
        depth_scale: metres per stored depth unit; default the dataset's ``scale_m`` attribute,
            else 0.001 for integer and 1 for floating datasets.
        allow_empty: accept frames with no valid pixel (refused by default).

    Returns:
        ``(depth, amplitude)``, float32 (T, 1, H, W): metres with NaN for invalid, camera units.
    """
    p = existing_file(path, "HDF5")
    with decoding(p, "an HDF5 file"), h5py.File(p, "r") as f:
        d, a, _, depth_scale = _stored_pair(f, p, depth_key, amplitude_key, depth_scale)
    check_same_shape(d, a, str(p))
    depth, amplitude = depth_from_stored(d, depth_scale), amplitude_from_stored(a)
    check_not_empty(depth, amplitude, str(p), allow_empty)
    return depth, amplitude


def write_hdf5(
    path,
    depth,
    amplitude,
    *,
    dtype: str = "uint16",
    amplitude_dtype: str | None = None,
    depth_scale: float | None = None,
    depth_key: str = "depth",
    amplitude_key: str = "amplitude",
    compression: str | None = None,
) -> Path:
    """Write a depth / amplitude pair as an HDF5 file (overwritten if it exists).

    Args:
        depth: (H, W), (T, H, W) or (T, 1, H, W) floating, metres (NaN / <= 0 invalid).
        amplitude: the same shape, camera units.
        dtype: ``"uint16"`` (depth in mm -- or ``depth_scale`` m -- with 0 invalid) or
            ``"float32"`` (metres, NaN invalid).
        amplitude_dtype: the amplitude's (default ``dtype``); ``"uint16"`` rounds to counts.
        depth_key, amplitude_key: dataset names.
        compression: an ``h5py`` filter (``"gzip"``, ``"lzf"``) or None.
    """
    d, a = as_frames(depth, "depth"), as_frames(amplitude, "amplitude")
    check_same_shape(d, a, "write_hdf5")
    if depth_key == amplitude_key:
        raise ValueError(f"depth_key and amplitude_key must differ, got {depth_key!r} twice")
    dd = depth_to_stored(d, dtype, depth_scale)
    aa = amplitude_to_stored(a, amplitude_dtype or dtype)
    scale = (
        depth_scale if depth_scale is not None else (METRES_PER_MM if dtype == "uint16" else 1.0)
    )
    p = output_path(path)
    with h5py.File(p, "w") as f:
        kw = dict(compression=compression, track_times=False)
        ds = f.create_dataset(depth_key, data=dd[0] if dd.shape[0] == 1 else dd, **kw)
        unit = "mm" if math.isclose(scale, METRES_PER_MM) else ("m" if scale == 1 else "")
        ds.attrs["unit"] = unit or f"{scale:g} m"
        ds.attrs["scale_m"] = float(scale)
        ds.attrs["invalid"] = "0" if dtype == "uint16" else "NaN"
        aset = f.create_dataset(amplitude_key, data=aa[0] if aa.shape[0] == 1 else aa, **kw)
        aset.attrs["unit"] = "camera units"
    return p
