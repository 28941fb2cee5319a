"""Pattern files of ``tof-fpn calibrate``: written by :func:`save_pattern`, read by
:func:`read_pattern`, and made the run-time module by :func:`load_pattern` (``--pattern FILE``).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from torch import nn

from ..analysis import ComplexPattern, FixedPattern, LearnedPattern
from ..io.patterns import read_pattern_file, write_pattern_file

__all__ = ["load_pattern", "read_pattern", "save_pattern"]


_KINDS = {ComplexPattern: "complex", LearnedPattern: "learned", FixedPattern: "fixed"}
_CLASSES = {kind: cls for cls, kind in _KINDS.items()}


def save_pattern(pattern: FixedPattern | ComplexPattern | LearnedPattern, path) -> Path:
    """Write ``pattern`` to the file ``path`` (:mod:`tof_fpn_torch.io.patterns`; parent
    directories are created)."""
    kind = _KINDS[type(pattern)]
    arrays, meta = pattern.to_arrays()
    return write_pattern_file(path, kind, arrays, meta)


def read_pattern(path) -> FixedPattern | ComplexPattern | LearnedPattern:
    """The pattern of a file written by :func:`save_pattern` (or :func:`calibrate`), either
    domain; files of earlier versions read unchanged.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a pattern file (the message says what is missing or wrong).
    """
    kind, arrays, meta = read_pattern_file(path)
    return _CLASSES[kind].from_arrays(arrays, meta)


def load_pattern(path) -> nn.Module:
    """The run-time module of a pattern file written by :func:`calibrate` (any kind)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"pattern file not found: {path}")
    try:
        with zipfile.ZipFile(p):
            pass
    except zipfile.BadZipFile:
        raise ValueError(f"{path} is not a pattern file (not an .npz archive)") from None
    return read_pattern(p).module()
