"""The table of file formats: every format the file layer reads or writes, found by a file's
suffix (or, for camera files, its name; for ROS 2 bags, a folder), with what it holds, its reader
and writer and the optional extra it needs.

Every tool of the package chooses the reader and the writer of a file here, with
:func:`format_for`, and nowhere else. A format is one :class:`FileFormat` record; :func:`register`
adds one (the built-in formats are registered when this module is imported), :func:`formats`
lists them, :func:`suffixes` gives the suffixes of a kind of file.

What a file holds decides how its functions are called:

* ``"pair member"`` (``.npy``, PNG, TIFF, raw): depth *or* amplitude, one file of a pair
  ``<name>_depth.<ext>`` + ``<name>_amplitude.<ext>``.
  ``reader(path, kind, *, height=None, width=None, depth_scale=None, allow_empty=False)`` ->
  float32 (T, 1, H, W); ``writer(path, x, kind, *, dtype="uint16", depth_scale=None)``;
  ``stored_reader(path, kind, *, height=None, width=None, depth_scale=None)`` -> ``(array as
  stored, metres per unit)``.
* ``"frame set"`` (``.npz``, HDF5): depth and amplitude in one file.
  ``reader(path, *, depth_scale=None, allow_empty=False)`` -> ``(depth, amplitude)``;
  ``writer(path, depth, amplitude, *, dtype="uint16", amplitude_dtype=None, depth_scale=None)``.
* ``"recording"`` (an Azure Kinect ``.mkv``, ROS bags, an ESPROS toolkit ``.h5`` found by its
  content): a camera's container, read whole.
  ``reader(path, *, depth_topic=None, amplitude_topic=None, depth_scale=None,
  allow_empty=False)`` -> :class:`~.recording.Recording`; no writer (a container is written as
  the package's recording ``.npz``).
* ``"camera file"`` (ADI ADTF3175 raw files): a camera's raw file, found by its name, which
  states its frame size; read as stored only.

Frame sets, recordings and camera files have
``stored_reader(path, amplitude_path=None, *, depth_scale=None)`` -> a list of
:class:`~._common.FrameSet` (the values as stored; a recording's as float32 metres). Every format
that ``tof-fpn clean`` can write back has ``rewriter(src, dst, arrays, sets, depth_scale=None)``:
``dst`` a copy of ``src`` with the depth of each frame set replaced by ``arrays[key]`` (``sets``:
the frame sets read, by key).

Call them through the record (:meth:`FileFormat.read`, :meth:`~FileFormat.write`,
:meth:`~FileFormat.read_stored`, :meth:`~FileFormat.write_like`): a format whose optional extra
is not installed then raises :class:`MissingExtraError` (an ``ImportError``) saying what to
install, e.g. ``pip install "tof_fpn_torch[mkv]"``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

from ._common import FrameSet, check_depth_bits, stored_scale
from ._table import (
    CAMERA_FILE,
    FRAME_SET,
    HOLDS,
    PAIR_MEMBER,
    RECORDING,
    FileFormat,
    MissingExtraError,
    format_for,
    format_of_name,
    formats,
    get_format,
    markdown_table,
    register,
    suffixes,
)
from .captures import (
    adi_interleaved_frame_sets,
    adi_interleaved_write_like,
    adi_pair_frame_sets,
    vendor_name,
)
from .espros import espros_frame_sets, is_espros_hdf5, read_espros_hdf5
from .hdf5 import hdf5_frame_sets, hdf5_write_like, read_hdf5, write_hdf5
from .images import (
    decode_png,
    decode_tiff,
    png_write_like,
    read_png,
    read_tiff,
    tiff_write_like,
    write_png,
    write_tiff,
)
from .matroska import read_azure_kinect_mkv
from .numpy_files import (
    decode_npy,
    npy_write_like,
    npz_frame_sets,
    npz_write_like,
    read_npy,
    read_npz,
    write_npy,
    write_npz,
)
from .raw import raw_write_like, read_raw, read_raw_array, require_frame_size, write_raw
from .recording import write_recording_like
from .rosbag import is_ros2_bag_dir, read_ros_bag

__all__ = [
    "CAMERA_FILE",
    "FRAME_SET",
    "HOLDS",
    "PAIR_MEMBER",
    "RECORDING",
    "FileFormat",
    "MissingExtraError",
    "format_for",
    "format_of_name",
    "formats",
    "get_format",
    "markdown_table",
    "register",
    "suffixes",
]


# --- adapters: the codecs' functions in the signatures of the table ---------------------------


def _size_in_file(read: Callable) -> Callable:
    """A pair-member reader of a format that stores its frame size (height / width unused)."""

    @functools.wraps(read)
    def reader(path, kind="depth", *, height=None, width=None, depth_scale=None, allow_empty=False):
        return read(path, kind, depth_scale=depth_scale, allow_empty=allow_empty)

    return reader


@functools.wraps(read_raw)
def _read_raw(path, kind="depth", *, height=None, width=None, depth_scale=None, allow_empty=False):
    require_frame_size(path, height, width)
    return read_raw(path, height, width, kind, depth_scale=depth_scale, allow_empty=allow_empty)


def _uint16_only(write: Callable) -> Callable:
    """A pair-member writer of a format that stores uint16 only."""

    @functools.wraps(write)
    def writer(path, x, kind="depth", *, dtype="uint16", depth_scale=None):
        if dtype != "uint16":
            suffix = Path(path).suffix.lower()
            raise ValueError(f"{path}: {suffix} files are uint16 only, got dtype {dtype!r}")
        return write(path, x, kind, depth_scale=depth_scale)

    return writer


def _stored_member(decode: Callable) -> Callable:
    def stored_reader(path, kind="depth", *, height=None, width=None, depth_scale=None):
        arr = decode(path)
        return arr, stored_scale(arr, depth_scale)

    stored_reader.__name__ = stored_reader.__qualname__ = decode.__name__
    return stored_reader


def _stored_png(path, kind="depth", *, height=None, width=None, depth_scale=None):
    """The stored image and its metres per unit: ``depth_scale``, else the ``depth_scale_m``
    text chunk, else 1 mm. An 8-bit depth PNG is refused unless ``depth_scale`` is given."""
    arr, text_scale = decode_png(path)
    if kind == "depth":
        check_depth_bits(arr, path, depth_scale)
    if depth_scale is None and text_scale is not None:
        depth_scale = text_scale
    return arr, stored_scale(arr, depth_scale)


_stored_png.__name__ = decode_png.__name__


def _stored_raw(path, kind="depth", *, height=None, width=None, depth_scale=None):
    require_frame_size(path, height, width)
    arr = read_raw_array(path, height, width, what=f"raw {kind}")
    return arr, stored_scale(arr, depth_scale)


_stored_raw.__name__ = read_raw_array.__name__


def _set_reader(read_sets: Callable) -> Callable:
    """A frame-set stored reader (``amplitude_path`` is not used: the file holds both)."""

    def stored_reader(path, amplitude_path=None, *, depth_scale=None):
        return read_sets(path, depth_scale)

    stored_reader.__name__ = stored_reader.__qualname__ = read_sets.__name__
    return stored_reader


def _one(write: Callable, *, scale: bool = False, source: bool = True) -> Callable:
    """A rewriter of a single-set file from ``write(src, dst, arr[, depth_scale])``."""

    def rewriter(src, dst, arrays, sets, depth_scale=None):
        args = ((src, dst) if source else (dst,)) + (arrays[""],)
        return write(*args, depth_scale) if scale else write(*args)

    rewriter.__name__ = rewriter.__qualname__ = write.__name__
    return rewriter


def _hdf5_rewriter(src, dst, arrays, sets, depth_scale=None):
    hdf5_write_like(src, dst, arrays, depth_scale)


_hdf5_rewriter.__name__ = hdf5_write_like.__name__


@functools.wraps(read_azure_kinect_mkv)
def _read_mkv(path, *, depth_topic=None, amplitude_topic=None, depth_scale=None, allow_empty=False):
    return read_azure_kinect_mkv(path, allow_empty=allow_empty)  # always mm, one pair of tracks


def _container_sets(read: Callable) -> Callable:
    """A recording's stored reader: float32 metres with NaN (``depth_scale`` 1), the reader's
    meta and timestamps kept."""

    def stored_reader(path, amplitude_path=None, *, depth_scale=None):
        if amplitude_path is not None:
            raise ValueError(f"{Path(path)} holds depth and amplitude; amplitude_path must be None")
        rec = read(path, depth_scale=depth_scale)
        ts = None if rec.timestamps_s is None else rec.timestamps_s.numpy()
        d, a = rec.depth[:, 0].numpy(), rec.amplitude[:, 0].numpy()
        return [FrameSet("", d, a, 1.0, tuple(d.shape), rec.meta.get("camera"), rec.meta, ts)]

    stored_reader.__name__ = stored_reader.__qualname__ = getattr(
        read, "__wrapped__", read
    ).__name__
    return stored_reader


def _vendor_kind(*kinds: str) -> Callable[[str], bool]:
    def matches(name: str) -> bool:
        v = vendor_name(name)
        return v is not None and v.kind in kinds

    return matches


# --- the built-in formats ---------------------------------------------------------------------

for _fmt in (
    FileFormat(
        "npz",
        FRAME_SET,
        "NumPy .npz archive (keys depth, amplitude; a recording too)",
        (".npz",),
        read_npz,
        write_npz,
        _set_reader(npz_frame_sets),
        _one(npz_write_like),
    ),
    FileFormat(
        "hdf5",
        FRAME_SET,
        "HDF5 file (datasets depth, amplitude; one set per group)",
        (".h5", ".hdf5"),
        read_hdf5,
        write_hdf5,
        _set_reader(hdf5_frame_sets),
        _hdf5_rewriter,
    ),
    FileFormat(
        "npy",
        PAIR_MEMBER,
        "NumPy .npy array",
        (".npy",),
        _size_in_file(read_npy),
        write_npy,
        _stored_member(decode_npy),
        _one(npy_write_like, source=False),
    ),
    FileFormat(
        "png",
        PAIR_MEMBER,
        "16-bit grey PNG",
        (".png",),
        _size_in_file(read_png),
        _uint16_only(write_png),
        _stored_png,
        _one(png_write_like, scale=True),
    ),
    FileFormat(
        "tiff",
        PAIR_MEMBER,
        "grey TIFF page or stack",
        (".tif", ".tiff"),
        _size_in_file(read_tiff),
        write_tiff,
        _stored_member(decode_tiff),
        _one(tiff_write_like),
    ),
    FileFormat(
        "raw",
        PAIR_MEMBER,
        "raw little-endian uint16 frames",
        (".bin", ".raw"),
        _read_raw,
        _uint16_only(write_raw),
        _stored_raw,
        _one(raw_write_like, source=False),
        needs_size=True,
    ),
    FileFormat(
        "mkv",
        RECORDING,
        "Azure Kinect .mkv recording",
        (".mkv",),
        _read_mkv,
        None,
        _container_sets(_read_mkv),
        write_recording_like,
        extra="mkv",
        requires=("av",),
    ),
    FileFormat(
        "ros1_bag",
        RECORDING,
        "ROS 1 bag (RealSense recordings too)",
        (".bag",),
        read_ros_bag,
        None,
        _container_sets(read_ros_bag),
        write_recording_like,
        extra="bag",
        requires=("rosbags",),
    ),
    FileFormat(
        "ros2_bag",
        RECORDING,
        "ROS 2 bag",
        (".mcap", ".db3"),
        read_ros_bag,
        None,
        _container_sets(read_ros_bag),
        write_recording_like,
        extra="bag",
        requires=("rosbags",),
        matches_folder=is_ros2_bag_dir,
        names="a folder with a rosbag2 `metadata.yaml`",
    ),
    FileFormat(
        "adi_depth_ir",
        CAMERA_FILE,
        "ADI ADTF3175 depth + IR raw pair",
        stored_reader=adi_pair_frame_sets,
        rewriter=_one(raw_write_like, source=False),
        matches_name=_vendor_kind("depth", "ir"),
        names="`<name>_depth_u16le_<H>x<W>.bin` + `<name>_ir_u16le_<H>x<W>.bin` (`.raw` too)",
    ),
    FileFormat(
        "adi_interleaved",
        CAMERA_FILE,
        "ADI ADTF3175 interleaved frame",
        stored_reader=adi_interleaved_frame_sets,
        rewriter=_one(adi_interleaved_write_like),
        matches_name=_vendor_kind("interleaved"),
        names="`<name>_interleaved_<H>x<W>.bin` (`.raw` too)",
    ),
    FileFormat(
        "espros_hdf5",
        RECORDING,
        "ESPROS epc-tofcam-toolkit HDF5 recording (point cloud)",
        reader=read_espros_hdf5,
        stored_reader=espros_frame_sets,
        rewriter=write_recording_like,
        matches_file=is_espros_hdf5,
        names="`.h5` / `.hdf5` by its content: root attribute `image_type`, datasets `frames_0`, "
        "`timestamps`",
    ),
):
    register(_fmt)
del _fmt
