"""Pattern files of ``tof-fpn calibrate``: written by :func:`save_pattern`, read by
:func:`read_pattern`, and made the run-time module by :func:`load_pattern` (``--pattern FILE``).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from torch import nn

from ..analysis import ComplexPattern, FixedPattern
from ..io.patterns import read_pattern_file, write_pattern_file

__all__ = ["load_pattern", "read_pattern", "save_pattern"]


def save_pattern(pattern: FixedPattern | ComplexPattern, path) -> Path:
    """Write ``pattern`` to the file ``path`` (:mod:`tof_fpn_torch.io.patterns`; parent
    directories are created)."""
    kind = "complex" if isinstance(pattern, ComplexPattern) else "fixed"
    arrays, meta = pattern.to_arrays()
    return write_pattern_file(path, kind, arrays, meta)


def read_pattern(path) -> FixedPattern | ComplexPattern:
    """The pattern of a file written by :func:`save_pattern` (or :func:`calibrate`), either
    domain; files of earlier versions read unchanged.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a pattern file (the message says what is missing or wrong).
    """
    kind, arrays, meta = read_pattern_file(path)
    cls = ComplexPattern if kind == "complex" else FixedPattern
    return cls.from_arrays(arrays, meta)


def load_pattern(path) -> nn.Module:
    """The run-time module of a pattern file written by :func:`calibrate` (either domain)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"pattern file not found: {path}")
    try:
        with zipfile.ZipFile(p):
            pass
    except zipfile.BadZipFile:
        raise ValueError(f"{path} is not a pattern file (not an .npz archive)") from None
    return read_pattern(p).module()
