"""Which files of a ``tof-fpn clean`` run come from one camera: :func:`camera_groups`.

A stage measured on data (``--stage auto``) is measured on one camera's frames and is right for
that camera only: the stripes of another sensor are elsewhere, or absent. So a run splits its jobs
into camera groups and measures and runs one pipeline per group. A job's group is named by a
:func:`camera_key` found without decoding any frame:

* the file format (:func:`~tof_fpn_torch.io.formats.format_for`): PNG, TIFF, ``.npy``, raw,
  ``.npz``, HDF5, the ADI vendor files;
* the frame size: a PNG's header (Pillow, not decoded), a TIFF's first page header, a ``.npy``'s
  header (in an ``.npz``: its ``depth.npy``), an HDF5 file's depth datasets (shapes only), an ADI
  vendor file's name, raw files the configured ``height`` x ``width``;
* a recording container (an ``.mkv``, a bag) is one camera by itself: one group per file.

A key reads ``"<format> <H>x<W>"`` (``"png 480x640"``), ``"<format> <file>"`` for a container
(``"mkv cam/take.mkv"``) and ``"<format> size unknown"`` when the header cannot be read (such a file
fails when it is read, with its reason).
"""

from __future__ import annotations

import os
import zipfile

import numpy as np

from ..io.camera_files import vendor_name
from ..io.formats import CAMERA_FILE, RECORDING, format_for
from .config import CleanConfig
from .plan import Job

__all__ = ["UNKNOWN_SIZE", "camera_groups", "camera_key"]

#: the size part of a key when the file's header cannot be read
UNKNOWN_SIZE = "size unknown"


def _npy_shape(fh) -> tuple[int, ...]:
    """The shape in the header of an open ``.npy`` stream (the data are not read)."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, _, _ = np.lib.format.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, _, _ = np.lib.format.read_array_header_2_0(fh)
    else:  # 3.0: a utf-8 header, read by numpy's own reader
        shape, _, _ = np.lib.format._read_array_header(fh, version)
    return tuple(shape)


def _hdf5_sizes(path: str) -> list[tuple[int, int]]:
    """The frame sizes of the depth datasets of the groups holding depth and amplitude."""
    import h5py

    sizes: list[tuple[int, int]] = []
    with h5py.File(path, "r") as f:
        groups = [f]
        f.visititems(lambda _, obj: groups.append(obj) if isinstance(obj, h5py.Group) else None)
        for g in groups:
            if "depth" in g and "amplitude" in g and isinstance(g["depth"], h5py.Dataset):
                size = tuple(g["depth"].shape[-2:])
                if size not in sizes:
                    sizes.append(size)
    return sizes


def _sizes(job: Job, fmt, config: CleanConfig) -> list[tuple[int, int]]:
    """The frame sizes the job's depth file states, read from headers only."""
    path = job.depth
    if fmt.holds == CAMERA_FILE:
        v = vendor_name(os.path.basename(path))
        return [(v.height, v.width)]
    if fmt.name == "png":
        from PIL import Image

        with Image.open(path) as im:  # the header only: nothing is decoded
            return [(im.height, im.width)]
    if fmt.name == "tiff":
        import tifffile

        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            return [(int(page.imagelength), int(page.imagewidth))]
    if fmt.name == "npy":
        with open(path, "rb") as fh:
            return [_npy_shape(fh)[-2:]]
    if fmt.name == "npz":
        with zipfile.ZipFile(path) as z, z.open("depth.npy") as fh:
            return [_npy_shape(fh)[-2:]]
    if fmt.name == "hdf5":
        return _hdf5_sizes(path)
    if fmt.needs_size and config.height is not None and config.width is not None:
        return [(int(config.height), int(config.width))]
    return []


def camera_key(job: Job, config: CleanConfig) -> str:
    """The camera group of ``job`` (module docstring), from its file format and the frame size
    its headers state; no frame is decoded. ``config``: the ``height`` / ``width`` of raw
    files."""
    fmt = format_for(job.depth)
    if fmt is None:  # not a format of the table: the planner does not make such jobs
        return f"{os.path.splitext(job.depth)[1].lower() or 'file'} {UNKNOWN_SIZE}"
    if fmt.holds == RECORDING:
        return f"{fmt.name} {job.name}"
    try:
        sizes = [tuple(int(n) for n in s) for s in _sizes(job, fmt, config)]
    except Exception:  # noqa: BLE001 -- a header that cannot be read: the reader says why later
        sizes = []
    sizes = [s for s in sizes if len(s) == 2]
    if not sizes:
        return f"{fmt.name} {UNKNOWN_SIZE}"
    return f"{fmt.name} " + "+".join(f"{h}x{w}" for h, w in sizes)


def camera_groups(jobs: list[Job], config: CleanConfig) -> list[tuple[str, list[Job]]]:
    """The runnable jobs (those without ``error``) grouped by :func:`camera_key`:
    ``[(key, jobs)]``, the jobs of a group in their order in ``jobs``, the groups in the order of
    their first job. Each group is one camera: a data-driven stage is measured on its own frames
    and runs on its own files."""
    groups: dict[str, list[Job]] = {}
    for job in jobs:
        if job.error is None:
            groups.setdefault(camera_key(job, config), []).append(job)
    return list(groups.items())
