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
* ``"recording"`` (an Azure Kinect ``.mkv``, ROS bags): a camera's container, read whole.
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
import importlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ._common import FrameSet, check_depth_bits, stored_scale
from .captures import (
    adi_interleaved_frame_sets,
    adi_interleaved_write_like,
    adi_pair_frame_sets,
    vendor_name,
)
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
from .recording import Recording, write_recording
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

#: one file of a depth / amplitude pair: depth *or* amplitude
PAIR_MEMBER = "pair member"
#: depth and amplitude in one file (an HDF5 file may hold several sets, one per group)
FRAME_SET = "frame set"
#: a camera's container, read whole as a :class:`~.recording.Recording`
RECORDING = "recording"
#: a camera's raw file, found by its name
CAMERA_FILE = "camera file"
#: what a file can hold
HOLDS: tuple[str, ...] = (PAIR_MEMBER, FRAME_SET, RECORDING, CAMERA_FILE)


class MissingExtraError(ImportError):
    """A format's optional dependency is not installed; the message names the extra."""


@dataclass(frozen=True)
class FileFormat:
    """One file format of the table.

    Attributes:
        name: the format's name in the table (``"npz"``, ``"mkv"``, ...).
        holds: what a file holds, one of :data:`HOLDS` (module docstring: the call signatures).
        title: what the format is, for messages and the docs.
        suffixes: lower-case suffixes with the dot; each belongs to one format of the table.
        reader, writer: the package's tensors from / to a file (None: not read / written so).
        stored_reader: the values as stored, for tools that write a file back as it came.
        rewriter: writes a file back as it came with only the depth replaced (None: cannot).
        extra: the optional extra of ``tof_fpn_torch`` the format needs (``pip install
            "tof_fpn_torch[<extra>]"``), None for none.
        requires: the modules that extra installs (imported when a file is read).
        matches_name: camera files: whether a file name (no folder) is one of this format.
        matches_folder: whether a folder is one file of this format (ROS 2 bags).
        names: camera files and folders: the naming rule, for the docs.
        needs_size: the frame size is not in the file (``height`` / ``width`` must be given).
    """

    name: str
    holds: str
    title: str
    suffixes: tuple[str, ...] = ()
    reader: Callable | None = None
    writer: Callable | None = None
    stored_reader: Callable | None = None
    rewriter: Callable | None = None
    extra: str | None = None
    requires: tuple[str, ...] = ()
    matches_name: Callable[[str], bool] | None = None
    matches_folder: Callable[[Path], bool] | None = None
    names: str = ""
    needs_size: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"a format's name must be a non-empty str, got {self.name!r}")
        if self.holds not in HOLDS:
            raise ValueError(
                f"format {self.name!r}: holds must be one of {HOLDS}, got {self.holds!r}"
            )
        bad = [
            s for s in self.suffixes if not (s.startswith(".") and s == s.lower() and len(s) > 1)
        ]
        if isinstance(self.suffixes, str) or bad:
            raise ValueError(
                f"format {self.name!r}: suffixes must be a tuple of lower-case '.ext' strings, "
                f"got {self.suffixes!r}"
            )
        if (self.extra is None) != (not self.requires):
            raise ValueError(f"format {self.name!r}: give extra and requires together")

    def check_available(self) -> None:
        """Raise :class:`MissingExtraError` naming the extra to install when a module the
        format needs cannot be imported."""
        for module in self.requires:
            try:
                importlib.import_module(module)
            except ImportError:
                raise MissingExtraError(
                    f"{self.title} files need the optional extra {self.extra!r} (the module "
                    f'{module!r} is not installed): pip install "tof_fpn_torch[{self.extra}]"'
                ) from None

    def _call(self, role: str, *args, **kwargs):
        fn = getattr(self, role)
        if fn is None:
            raise ValueError(f"{self.title} ({self.name}) files have no {role.replace('_', ' ')}")
        self.check_available()
        return fn(*args, **kwargs)

    def read(self, *args, **kwargs):
        """:attr:`reader` (module docstring: its arguments by :attr:`holds`)."""
        return self._call("reader", *args, **kwargs)

    def write(self, *args, **kwargs):
        """:attr:`writer`."""
        return self._call("writer", *args, **kwargs)

    def read_stored(self, *args, **kwargs):
        """:attr:`stored_reader`."""
        return self._call("stored_reader", *args, **kwargs)

    def write_like(self, *args, **kwargs):
        """:attr:`rewriter`."""
        return self._call("rewriter", *args, **kwargs)


_FORMATS: dict[str, FileFormat] = {}
_BY_SUFFIX: dict[str, FileFormat] = {}


def register(fmt: FileFormat, *, replace: bool = False) -> FileFormat:
    """Add ``fmt`` to the table (``replace``: in place of the format of its name).

    ``ValueError`` for a name already registered (without ``replace``) and for a suffix that
    belongs to another format: every suffix maps to exactly one format."""
    if not isinstance(fmt, FileFormat):
        raise ValueError(f"register takes a FileFormat, got {type(fmt).__name__}")
    old = _FORMATS.get(fmt.name)
    if old is not None and not replace:
        raise ValueError(f"a format {fmt.name!r} is registered already (replace=True replaces it)")
    taken = {s: _BY_SUFFIX[s].name for s in fmt.suffixes if _BY_SUFFIX.get(s, fmt).name != fmt.name}
    if taken or len(set(fmt.suffixes)) != len(fmt.suffixes):
        raise ValueError(f"format {fmt.name!r}: suffix(es) given twice or taken: {taken}")
    if old is not None:
        for s in old.suffixes:
            del _BY_SUFFIX[s]
    _FORMATS[fmt.name] = fmt
    _BY_SUFFIX.update(dict.fromkeys(fmt.suffixes, fmt))
    return fmt


def formats(*holds: str) -> tuple[FileFormat, ...]:
    """The registered formats in their order of registration (only those holding one of
    ``holds``, if given)."""
    return tuple(f for f in _FORMATS.values() if not holds or f.holds in holds)


def get_format(name: str) -> FileFormat:
    """The format registered as ``name`` (``ValueError`` listing the names if none)."""
    if name not in _FORMATS:
        raise ValueError(f"no file format {name!r}; the formats are {list(_FORMATS)}")
    return _FORMATS[name]


def suffixes(*holds: str) -> tuple[str, ...]:
    """The suffixes of the formats holding one of ``holds`` (all formats if none given)."""
    return tuple(s for f in formats(*holds) for s in f.suffixes)


def format_of_name(name, *, by_name: bool = True) -> FileFormat | None:
    """The format of a file name (no file system access): a camera file's naming rule first
    (unless ``by_name`` is False), then the suffix, any case; None for a file of no format."""
    base = os.path.basename(os.fspath(name))
    if by_name:
        for fmt in _FORMATS.values():
            if fmt.matches_name is not None and fmt.matches_name(base):
                return fmt
    return _BY_SUFFIX.get(Path(base).suffix.lower())


def format_for(path, *, by_name: bool = True) -> FileFormat | None:
    """The format of ``path``: a folder is one file of the format whose ``matches_folder``
    takes it (a ROS 2 bag), else of none; a file is by :func:`format_of_name`. ``by_name=False``:
    by suffix only (the frame files of :func:`~.pairs.read_pair` and
    :class:`~.dataset.FrameDataset`, where an ADI name is a raw file like any other)."""
    p = Path(path)
    if p.is_dir():
        return next((f for f in formats() if f.matches_folder and f.matches_folder(p)), None)
    return format_of_name(p.name, by_name=by_name)


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


def write_recording_like(src, dst, arrays: dict[str, np.ndarray], sets: dict, depth_scale=None):
    """A container's cleaned depth as the package's recording ``.npz`` (the reader's meta and
    timestamps, its amplitude): there is no faithful writer for the containers."""
    fs = sets[""]
    rec = Recording(
        torch.from_numpy(arrays[""]),
        torch.from_numpy(fs.amplitude),
        fs.meta,
        timestamps_s=fs.timestamps_s,
    )
    write_recording(dst, rec, allow_empty=True)


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
):
    register(_fmt)
del _fmt


def _function_name(fn: Callable | None) -> str:
    if fn is None:
        return "--"
    return f"`{getattr(fn, '__wrapped__', fn).__name__}`"


def markdown_table() -> str:
    """The table of formats as a Markdown table (docs/io.md holds it)."""
    rows = [
        "| format | files | holds | reader | writer | stored reader | written back by | extra |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for f in formats():
        files = ", ".join(f"`{s}`" for s in f.suffixes)
        files = "; ".join(x for x in (files, f.names) if x)
        extra = f"`{f.extra}`" if f.extra else "--"
        rows.append(
            f"| `{f.name}`: {f.title} | {files} | {f.holds} | {_function_name(f.reader)} | "
            f"{_function_name(f.writer)} | {_function_name(f.stored_reader)} | "
            f"{_function_name(f.rewriter)} | {extra} |"
        )
    return "\n".join(rows) + "\n"
