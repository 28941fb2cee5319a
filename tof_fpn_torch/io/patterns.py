"""Pattern files of ``tof-fpn calibrate``: a calibrated fixed pattern, depth or complex domain.

An uncompressed ``.npz`` that ``numpy.load(path)`` reads (no pickle): float64 little-endian arrays
and ``meta_json`` (uint8, the UTF-8 JSON of the pattern's other fields, with its ``format``):

- depth domain (``format`` ``tof_fpn_torch.fixed_pattern/1``): ``column_offset`` (W,),
  ``row_offset`` (H,), ``pixel_offset`` (H, W) (zeros when not calibrated), ``column_gain`` (W,)
  (ones when not calibrated), ``column_se`` (W,);
- complex domain (``tof_fpn_torch.complex_pattern/1``): ``column_offset_re``,
  ``column_offset_im`` (W,), ``row_offset_re``, ``row_offset_im`` (H,) (zeros when not
  calibrated), ``column_pixels`` (W,);
- learned from a folder (``tof_fpn_torch.learned_pattern/1``): ``column_offset`` (W,),
  ``row_offset`` (H,), ``pixel_offset`` (H, W) (zeros when not kept), ``readout_re``,
  ``readout_im`` (W,) (the column read-out offset, zeros when none; ``modulation_frequency_hz`` in
  the metadata).

This module owns the format and speaks plain tensors: :func:`write_pattern_file` takes the arrays
and the metadata, :func:`read_pattern_file` returns them (float64 CPU tensors and a dict);
:class:`~tof_fpn_torch.analysis.FixedPattern` and :class:`~tof_fpn_torch.analysis.ComplexPattern`
convert to and from them (``to_arrays`` / ``from_arrays``), and
:func:`tof_fpn_torch.clean.pattern.save_pattern` / :func:`~tof_fpn_torch.clean.pattern.read_pattern`
join the two. Files written by earlier versions (whose ``.npy`` entries the analysis layer wrote
by hand, same names, same format 1) read unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from .numpy_files import load_npz, save_npz

__all__ = ["PATTERN_FORMATS", "read_pattern_file", "write_pattern_file"]

#: kind -> (``format`` written in ``meta_json``, what the kind is called, the arrays it must hold)
PATTERN_FORMATS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "fixed": (
        "tof_fpn_torch.fixed_pattern/1",
        "fixed-pattern",
        ("column_offset", "row_offset", "pixel_offset", "column_gain"),
    ),
    "complex": (
        "tof_fpn_torch.complex_pattern/1",
        "complex-pattern",
        ("column_offset_re", "column_offset_im", "row_offset_re", "row_offset_im"),
    ),
    "learned": (
        "tof_fpn_torch.learned_pattern/1",
        "learned-pattern",
        ("column_offset", "row_offset", "pixel_offset", "readout_re", "readout_im"),
    ),
}


def _kind_of(names) -> str:
    """The kind of an archive from the arrays it holds (complex ones have ``column_offset_re``,
    learned ones ``readout_re``)."""
    if "readout_re" in names:
        return "learned"
    return "complex" if "column_offset_re" in names else "fixed"


def write_pattern_file(path, kind: str, arrays: dict[str, torch.Tensor], meta: dict) -> Path:
    """Write a pattern file (module docstring); parent directories are created.

    Args:
        path: the ``.npz`` to write.
        kind: ``"fixed"`` (depth domain), ``"complex"`` or ``"learned"``.
        arrays: name -> tensor, stored as float64 (the arrays of the kind, and any others).
        meta: the JSON-able scalar fields; ``format`` is set from ``kind``.
    """
    if kind not in PATTERN_FORMATS:
        raise ValueError(f"kind must be one of {sorted(PATTERN_FORMATS)}, got {kind!r}")
    fmt, name, required = PATTERN_FORMATS[kind]
    missing = sorted(set(required) - set(arrays))
    if missing:
        raise ValueError(f"a {name} file needs the arrays {missing}")
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    out = {k: t.detach().to(device="cpu", dtype=torch.float64).numpy() for k, t in arrays.items()}
    text = json.dumps({"format": fmt, **{k: v for k, v in meta.items() if k != "format"}})
    out["meta_json"] = np.frombuffer(text.encode(), dtype=np.uint8)
    return save_npz(p, out)


def read_pattern_file(path) -> tuple[str, dict[str, torch.Tensor], dict]:
    """``(kind, arrays, meta)`` of a pattern file: ``"fixed"``, ``"complex"`` or ``"learned"``, the arrays as
    float64 CPU tensors (``meta_json`` decoded into ``meta``, ``format`` included).

    Raises:
        FileNotFoundError: no such file.
        ValueError: not an ``.npz`` archive (:class:`~tof_fpn_torch.io.FormatError`), arrays of its
            kind missing (``"... is not a fixed-pattern file: missing [...]"``), or another format.
    """
    raw = load_npz(path, "a pattern file")
    kind = _kind_of(raw)
    fmt, name, required = PATTERN_FORMATS[kind]
    missing = sorted({*required, "meta_json"} - set(raw))
    if missing:
        raise ValueError(f"{path} is not a {name} file: missing {missing}")
    meta = json.loads(raw.pop("meta_json").astype(np.uint8).tobytes().decode())
    if meta.get("format") != fmt:
        raise ValueError(f"{path}: format {meta.get('format')!r}, expected {fmt!r}")
    arrays = {k: torch.from_numpy(np.array(v, dtype=np.float64)) for k, v in raw.items()}
    return kind, arrays, meta
