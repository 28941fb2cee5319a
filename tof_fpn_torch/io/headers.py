"""Frame sizes from file headers: :func:`frame_sizes`, what a file states about its frames without
decoding them (the folder tools group files by camera with it, ``tof-fpn clean``).

* PNG: the image header (Pillow opens it lazily; no pixel is decoded);
* TIFF: the first page's header (``tifffile``);
* ``.npy``: its header; ``.npz``: the header of its ``depth.npy``;
* HDF5: the shapes of the ``depth`` datasets of the groups holding ``depth`` and ``amplitude``
  (no data read);
* ADI vendor files: the size in the name;
* ESPROS epc-tofcam-toolkit HDF5 files: a point cloud's region of interest (its root attributes),
  the last two axes of an amplitude-only recording;
* raw files: the ``height`` / ``width`` given (the file does not state one).

The other recording containers (``.mkv``, bags) are not opened: ``[]``, as for any file whose header cannot
be read (its reader says why when the file is read).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from ._table import CAMERA_FILE, format_for
from .captures import vendor_name
from .espros import espros_frame_sizes

__all__ = ["frame_sizes"]


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


def _png(path) -> list[tuple[int, int]]:
    from PIL import Image

    with Image.open(path) as im:  # the header only: nothing is decoded
        return [(im.height, im.width)]


def _tiff(path) -> list[tuple[int, int]]:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        return [(int(page.imagelength), int(page.imagewidth))]


def _npy(path) -> list[tuple[int, ...]]:
    with open(path, "rb") as fh:
        return [_npy_shape(fh)[-2:]]


def _npz(path) -> list[tuple[int, ...]]:
    with zipfile.ZipFile(path) as z, z.open("depth.npy") as fh:
        return [_npy_shape(fh)[-2:]]


def _hdf5(path) -> list[tuple[int, ...]]:
    import h5py

    sizes: list[tuple[int, ...]] = []
    with h5py.File(path, "r") as f:
        groups = [f]
        f.visititems(lambda _, obj: groups.append(obj) if isinstance(obj, h5py.Group) else None)
        for g in groups:
            if "depth" in g and "amplitude" in g and isinstance(g["depth"], h5py.Dataset):
                size = tuple(g["depth"].shape[-2:])
                if size not in sizes:
                    sizes.append(size)
    return sizes


_BY_FORMAT = {
    "png": _png,
    "tiff": _tiff,
    "npy": _npy,
    "npz": _npz,
    "hdf5": _hdf5,
    "espros_hdf5": espros_frame_sizes,
}


def frame_sizes(path, *, height: int | None = None, width: int | None = None) -> list[tuple]:
    """The frame sizes ``(H, W)`` a depth file (or a file holding depth and amplitude) states in
    its header or name, in order, each once; ``[]`` when it states none or its header cannot be
    read (module docstring). ``height`` / ``width``: the size of raw files."""
    fmt = format_for(path)
    if fmt is None:
        return []
    if fmt.holds == CAMERA_FILE:
        v = vendor_name(os.path.basename(os.fspath(path)))
        return [] if v is None else [(v.height, v.width)]
    if fmt.needs_size:
        return [] if height is None or width is None else [(int(height), int(width))]
    read = _BY_FORMAT.get(fmt.name)
    if read is None or not Path(path).is_file():
        return []
    try:
        sizes = read(path)
    except Exception:  # noqa: BLE001 -- a header that cannot be read: its reader says why later
        return []
    return [tuple(int(n) for n in s) for s in sizes if len(s) == 2]
