"""The versioned ``.npz`` container shared by the recording and the scene formats.

An archive holds ``content`` (0-d str: what it is, e.g. ``"tof_fpn_torch.recording"``),
``format_version`` (0-d int), ``meta`` (0-d str: a JSON object) and the format's arrays, written
deterministically by :func:`tof_fpn_torch.io.numpy_files.save_npz`. Reading checks the content,
the version and the key set, so a scene read as a recording, a newer file or a typo in a key is a
clear :class:`FormatError`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from ._common import FormatError
from .numpy_files import load_npz, save_npz

__all__ = ["jsonable", "read_container", "write_container"]

_HEADER = ("content", "format_version", "meta")


def jsonable(value):
    """``value`` with tensors / NumPy scalars and arrays as numbers / lists and tuples as lists,
    so that ``json.dumps`` takes it; ``ValueError`` naming what cannot be stored."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu()
        return value.item() if value.numel() == 1 and value.dim() == 0 else value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, dict):
        bad = [k for k in value if not isinstance(k, str)]
        if bad:
            raise ValueError(f"meta keys must be str, got {bad!r}")
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"meta values must be finite (JSON has no NaN / inf), got {value!r}")
        return value
    raise ValueError(f"meta values must be JSON data, got {value!r} ({type(value).__name__})")


def meta_json(meta: dict) -> str:
    """The meta dict as canonical JSON (sorted keys, no NaN)."""
    if not isinstance(meta, dict):
        raise ValueError(f"meta must be a dict, got {type(meta).__name__}")
    return json.dumps(jsonable(meta), sort_keys=True, allow_nan=False)


def write_container(
    path, content: str, version: int, meta: dict, arrays: dict[str, np.ndarray], compress: bool
) -> Path:
    header = {
        "content": np.array(content),
        "format_version": np.array(version, dtype=np.int64),
        "meta": np.array(meta_json(meta)),
    }
    return save_npz(path, {**header, **arrays}, compress)


def _scalar(arrays: dict, key: str, kind: str, p) -> object:
    if key not in arrays:
        raise FormatError(f"{p}: no {key!r} entry; not a tof_fpn_torch recording / scene file")
    a = arrays[key]
    if a.shape != () or a.dtype.kind not in kind:
        raise FormatError(f"{p}: {key!r} must be a 0-d {kind!r} array, got {a.dtype} {a.shape}")
    return a.item()


def read_container(
    path, content: str, version: int, required: tuple[str, ...], optional: tuple[str, ...]
) -> tuple[dict[str, np.ndarray], dict]:
    """``(arrays, meta)`` of a container holding ``content`` at ``format_version <= version``,
    with every ``required`` and no key outside ``required + optional`` (besides the header)."""
    arrays = load_npz(path, f"a {content} file")
    found = _scalar(arrays, "content", "U", path)
    if found != content:
        raise FormatError(f"{path}: holds {found!r}, expected {content!r}")
    v = _scalar(arrays, "format_version", "iu", path)
    if not 1 <= v <= version:
        raise FormatError(
            f"{path}: format_version {v}; this reader knows versions 1 .. {version} "
            "(a newer tof_fpn_torch wrote it?)"
        )
    try:
        meta = json.loads(_scalar(arrays, "meta", "U", path))
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: meta is not valid JSON: {exc}") from exc
    if not isinstance(meta, dict):
        raise FormatError(f"{path}: meta must be a JSON object, got {type(meta).__name__}")
    keys = set(arrays) - set(_HEADER)
    missing = [k for k in required if k not in keys]
    unknown = sorted(keys - set(required) - set(optional))
    if missing or unknown:
        raise FormatError(
            f"{path}: missing array(s) {missing}, unknown array(s) {unknown}; a {content} "
            f"v{version} file holds {list(required)} and optionally {list(optional)}"
        )
    return {k: arrays[k] for k in keys}, meta
