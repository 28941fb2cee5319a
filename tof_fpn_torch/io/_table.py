"""The registry behind :mod:`.formats`: the :class:`FileFormat` record, :func:`register` and the
lookups. It imports no module of the file layer, so every module may import it; :mod:`.formats`
registers the built-in formats and is the public face of the table.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

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
        matches_file: files found by their content (an ESPROS toolkit HDF5 file): whether an
            existing file is one of this format, by its structure (cheap, never raises);
            :func:`format_for` asks it before the suffix, :func:`format_of_name` never.
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
    matches_file: Callable[[Path], bool] | None = None
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
    takes it (a ROS 2 bag), else of none; a file is by :func:`format_of_name`'s naming rules,
    then by its content (a format whose ``matches_file`` takes it: an ESPROS toolkit ``.h5``),
    then by its suffix. ``by_name=False``: by suffix only (the frame files of
    :func:`~.pairs.read_pair` and :class:`~.dataset.FrameDataset`, where an ADI name is a raw
    file like any other)."""
    p = Path(path)
    if p.is_dir():
        return next((f for f in formats() if f.matches_folder and f.matches_folder(p)), None)
    fmt = format_of_name(p.name, by_name=by_name)
    if by_name and (fmt is None or fmt.matches_name is None):
        found = next((f for f in formats() if f.matches_file and f.matches_file(p)), None)
        if found is not None:
            return found
    return fmt


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
