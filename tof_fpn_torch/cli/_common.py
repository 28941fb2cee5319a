"""What the sub-commands share: argument types that say what is allowed, output paths, threads,
a missing optional extra as one line (:func:`extras_named`).

Output paths are kept as the strings the user typed: they are checked before any work is done
(:func:`check_output_file`, :func:`check_output_dir`), the directories they need are created by
:func:`output_dirs` (which reports the ones it made) and they are printed exactly as written, so
every path printed is a file or directory that exists under that name.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

#: Smallest scene side (``--size``) the paper's synthetic data accept
#: (:mod:`tof_fpn_torch.paper_data`; ``tests/test_cli.py`` checks the two agree).
MIN_SIZE = 32
#: Largest scene side (``--size``): memory and time grow with its square; 4096 is 20 times the
#: CamCube side and takes about a minute for the demo, while 100 000 would exhaust the memory.
MAX_SIZE = 4096
#: Largest ``--threads``: the CPUs of this machine (torch crashes on absurd counts, e.g. 100 000).
MAX_THREADS = os.cpu_count() or 1
#: Smallest ``--h``: below it NLM keeps every pixel as it is, and below ~1e-154 ``h**2``
#: underflows to 0.
MIN_H = 1e-6


class UsageError(ValueError):
    """A bad argument found after parsing: ``main`` prints it as one line and returns 2."""


@contextmanager
def extras_named() -> Iterator[None]:
    """Turn a file format's missing optional extra (:class:`tof_fpn_torch.io.MissingExtraError`,
    an ``ImportError`` whose message names ``pip install "tof_fpn_torch[<extra>]"``) into a
    :class:`UsageError`: one line naming the extra, no traceback. Other errors pass."""
    try:
        yield
    except ImportError as exc:
        from ..io import MissingExtraError

        if isinstance(exc, MissingExtraError):
            raise UsageError(str(exc)) from None
        raise


def _allowed(lo: float | None, hi: float | None) -> str:
    if lo is not None and hi is not None:
        return f" in [{lo:g}, {hi:g}]"
    if lo is not None:
        return f" >= {lo:g}"
    if hi is not None:
        return f" <= {hi:g}"
    return ""


def int_arg(lo: int | None = None, hi: int | None = None) -> Callable[[str], int]:
    """argparse ``type``: an int in ``[lo, hi]`` (either bound may be None)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"must be an int{_allowed(lo, hi)}, got {text!r}")
        return value

    parse.__name__ = "int"
    return parse


def float_arg(lo: float | None = None, *, open_lo: bool = False) -> Callable[[str], float]:
    """argparse ``type``: a finite float ``>= lo`` (``> lo`` with ``open_lo``)."""
    allowed = "" if lo is None else f" {'>' if open_lo else '>='} {lo:g}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (lo is None or (value > lo if open_lo else value >= lo))
        if not ok:
            raise argparse.ArgumentTypeError(f"must be a finite number{allowed}, got {text!r}")
        return value

    parse.__name__ = "float"
    return parse


def threads_arg() -> Callable[[str], int]:
    return int_arg(1, MAX_THREADS)


def set_threads(n: int) -> None:
    """``torch.set_num_threads(n)`` (``n`` checked by :func:`threads_arg` when parsed)."""
    import torch

    if not 1 <= n <= MAX_THREADS:
        raise UsageError(f"--threads must be an int in [1, {MAX_THREADS}], got {n}")
    torch.set_num_threads(n)


def _check_parents(option: str, text: str, directory: Path) -> None:
    """The nearest existing one of ``directory`` and its parents must be a writable directory."""
    for d in (directory, *directory.parents):
        if os.path.lexists(d):
            if not d.is_dir():
                raise UsageError(f"{option} {text!r}: {str(d)!r} is a file, not a directory")
            if not os.access(d, os.W_OK | os.X_OK):
                raise UsageError(f"{option} {text!r}: directory {str(d)!r} is not writable")
            return


def check_output_file(option: str, text: str, suffixes: tuple[str, ...] = ()) -> None:
    """Refuse (``UsageError``) a file path that cannot be written under exactly that name.

    ``suffixes``: the allowed file name endings (lower case, with the dot); empty: any.
    """
    if not text:
        raise UsageError(f"{option} must be a file path, got {text!r}")
    path = Path(text)
    if suffixes and path.suffix.lower() not in suffixes:
        raise UsageError(
            f"{option} must end in {' or '.join(suffixes)}, got {text!r}"
            if len(suffixes) <= 2
            else f"{option} must end in one of {', '.join(suffixes)}, got {text!r}"
        )
    if os.path.isdir(text) or text.endswith(("/", os.sep)):
        raise UsageError(f"{option} must be a file path, got the directory {text!r}")
    _check_parents(option, text, path.parent)


def check_output_dir(option: str, text: str) -> None:
    """Refuse (``UsageError``) a directory path that is a file or lies below one."""
    if not text:
        raise UsageError(f"{option} must be a directory path, got {text!r}")
    path = Path(text)
    if os.path.lexists(text) and not os.path.isdir(text):
        raise UsageError(f"{option} {text!r} is a file, not a directory")
    _check_parents(option, text, path)


@contextmanager
def output_dirs(*dirs: str) -> Iterator[list[str]]:
    """Create the missing ones of ``dirs`` (paths as written; ``""`` is the current directory).

    Yields the list of those created, as written, for the caller to report. If the body raises,
    the directories made here that are still empty are removed again.
    """
    made: list[str] = []  # every level created, shallowest first
    created: list[str] = []
    try:
        for d in dirs:
            if not d or os.path.isdir(d):
                continue
            missing = []
            for level in (d, *map(str, Path(d).parents)):
                if os.path.isdir(level):
                    break
                missing.append(level)
            os.makedirs(d)
            made.extend(reversed(missing))
            created.append(d)
        yield created
    except BaseException:
        for level in reversed(made):
            try:
                os.rmdir(level)
            except OSError:
                pass
        raise


def report_created(created: list[str]) -> None:
    for d in created:
        print(f"created directory {d}")


def join(directory: str, name: str) -> str:
    """``name`` inside ``directory``, the directory as the user wrote it."""
    return os.path.join(directory, name)
