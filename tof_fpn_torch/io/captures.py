"""Camera-specific raw files: Analog Devices ADTF3175 frames and Kinect v2 P0 tables.

* ADTF3175 depth + IR: two raw uint16 LE files of 512 x 512 (depth in mm, 0 invalid; IR / active
  brightness in 12-bit counts) -- :func:`read_adi_depth_ir` (see :mod:`.raw`).
* ADTF3175 interleaved frame: 5 bytes per pixel, row-major: depth uint16 LE (mm, 0 invalid),
  confidence uint8, active brightness (AB) uint16 LE -- :func:`read_adi_interleaved` /
  :func:`write_adi_interleaved` (a read-then-write round trip is byte-exact).
* Kinect v2 P0 tables: 3 planes of 424 x 512 uint16 LE, no header; a plane per modulation frequency
  (80, 16, 120 MHz, libfreenect2's order); ``65536`` units are one turn (2 pi rad) --
  :func:`read_kinect_v2_p0` returns radians in [0, 2 pi) / :func:`write_kinect_v2_p0`.

All readers return float32 (B, C, H, W) CPU tensors with the units stated on each.

The ADI files are also found by their vendor names (:func:`vendor_name`; ``<H>x<W>`` is rows x
columns, any size, ``.bin`` or ``.raw``, any case):

* ``<name>_depth_u16le_<H>x<W>.bin`` + ``<name>_ir_u16le_<H>x<W>.bin``: depth (mm) + IR (counts);
* ``<name>_interleaved_<H>x<W>.bin``: the interleaved frame.

:func:`adi_pair_frame_sets` and :func:`adi_interleaved_frame_sets` read such files as stored
(what ``tof-fpn clean`` reads, camera ``adtf3175``, the size from the name);
:func:`adi_interleaved_write_like` writes an interleaved file back with only its depth bytes
replaced (confidence and AB byte for byte).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ._common import (
    FormatError,
    FrameSet,
    amplitude_from_stored,
    amplitude_to_stored,
    as_frames,
    check_not_empty,
    check_same_shape,
    check_scale,
    depth_from_stored,
    depth_to_stored,
    existing_file,
    output_path,
)
from .raw import RAW_DTYPE, read_raw, read_raw_array

__all__ = [
    "ADI_INTERLEAVED_DTYPE",
    "ADI_SHAPE",
    "KINECT_V2_P0_SHAPE",
    "P0_UNITS_PER_TURN",
    "VendorName",
    "adi_interleaved_frame_sets",
    "adi_interleaved_write_like",
    "adi_pair_frame_sets",
    "read_adi_depth_ir",
    "read_adi_interleaved",
    "read_kinect_v2_p0",
    "vendor_name",
    "vendor_partner",
    "write_adi_interleaved",
    "write_kinect_v2_p0",
]

#: (height, width) of the ADTF3175 frames (megapixel mode binned / QMP)
ADI_SHAPE: tuple[int, int] = (512, 512)
#: (planes, height, width) of the Kinect v2 P0 tables
KINECT_V2_P0_SHAPE: tuple[int, int, int] = (3, 424, 512)
#: stored units per turn of phase in the P0 tables (65536 = 2 pi rad)
P0_UNITS_PER_TURN: int = 1 << 16
#: the interleaved pixel: depth uint16 LE (mm), confidence uint8, active brightness uint16 LE
_INTERLEAVED = np.dtype([("depth", "<u2"), ("confidence", "u1"), ("ab", "<u2")])
#: the interleaved pixel as a NumPy structured dtype (fields ``depth``, ``confidence``, ``ab``)
ADI_INTERLEAVED_DTYPE: np.dtype = _INTERLEAVED


def read_adi_depth_ir(
    depth_path,
    ir_path,
    height: int = ADI_SHAPE[0],
    width: int = ADI_SHAPE[1],
    *,
    allow_empty: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """ADTF3175 depth and IR raw frames (uint16 LE each, ``height x width``).

    Returns:
        ``(depth, ir)``, float32 (T, 1, H, W): depth in metres (stored mm; 0 -> NaN), IR in
        counts (12-bit active brightness).
    """
    depth = read_raw(depth_path, height, width, "depth", allow_empty=True)
    ir = read_raw(ir_path, height, width, "amplitude")
    check_same_shape(depth, ir, f"{depth_path} / {ir_path}")
    check_not_empty(depth, ir, str(depth_path), allow_empty)
    return depth, ir


def read_adi_interleaved(
    path, height: int = ADI_SHAPE[0], width: int = ADI_SHAPE[1], *, allow_empty: bool = False
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """ADTF3175 interleaved frame: 5 bytes per pixel (depth u16 LE mm, confidence u8, AB u16 LE).

    Returns:
        ``(depth, confidence, ab)``, float32 (T, 1, H, W): depth in metres (0 mm -> NaN), the
        camera's confidence code (0 .. 255, unscaled) and active brightness in counts.
    """
    arr = read_raw_array(path, height, width, dtype=_INTERLEAVED, what="ADTF3175 interleaved")
    depth = depth_from_stored(arr["depth"])
    ab = amplitude_from_stored(arr["ab"])
    check_not_empty(depth, ab, str(path), allow_empty)
    return depth, amplitude_from_stored(arr["confidence"]), ab


def write_adi_interleaved(path, depth, confidence, ab) -> Path:
    """Write an ADTF3175 interleaved file from depth (metres, NaN invalid -> 0 mm), confidence
    (integer codes 0 .. 255) and active brightness (counts); each (H, W), (T, H, W) or
    (T, 1, H, W) floating."""
    d = as_frames(depth, "depth")
    c = as_frames(confidence, "confidence")
    a = as_frames(ab, "ab")
    check_same_shape(d, c, "write_adi_interleaved (depth / confidence)")
    check_same_shape(d, a, "write_adi_interleaved (depth / ab)")
    cc = np.asarray(c, dtype=np.float64)
    if not np.isfinite(cc).all() or cc.min() < 0 or cc.max() > 255 or (cc != np.rint(cc)).any():
        raise ValueError("confidence must hold integer codes in [0, 255] (stored as uint8)")
    out = np.empty(d.shape, dtype=_INTERLEAVED)
    out["depth"] = depth_to_stored(d, "uint16")
    out["confidence"] = cc.astype(np.uint8)
    out["ab"] = amplitude_to_stored(a, "uint16")
    p = output_path(path)
    out.tofile(p)
    return p


def read_kinect_v2_p0(path) -> torch.Tensor:
    """Kinect v2 P0 tables (3 x 424 x 512 uint16 LE, no header) as phase offsets.

    Returns:
        float32 (3, 1, 424, 512) in radians, [0, 2 pi): one table per modulation frequency
        (80, 16, 120 MHz), stored ``u`` -> ``2 pi u / 65536``.
    """
    n, h, w = KINECT_V2_P0_SHAPE
    arr = read_raw_array(path, h, w, frames=n, what="Kinect v2 P0 table")
    rad = arr.astype(np.float64) * (2.0 * math.pi / P0_UNITS_PER_TURN)
    return torch.from_numpy(rad.astype(np.float32)).unsqueeze(1)


def write_kinect_v2_p0(path, p0) -> Path:
    """Write P0 tables from phase offsets in radians ((3, 1, 424, 512) or (3, 424, 512)
    floating; any finite value, wrapped to one turn), as 3 x 424 x 512 uint16 LE."""
    x = as_frames(p0, "p0")
    if x.shape != KINECT_V2_P0_SHAPE:
        raise ValueError(f"p0 must have shape {list(KINECT_V2_P0_SHAPE)}, got {list(x.shape)}")
    x = x.astype(np.float64)
    if not np.isfinite(x).all():
        raise ValueError("p0 must be finite (radians)")
    units = np.rint(x * (P0_UNITS_PER_TURN / (2.0 * math.pi))) % P0_UNITS_PER_TURN
    p = output_path(path)
    units.astype(RAW_DTYPE).tofile(p)
    return p


_ADI_PAIR = re.compile(
    r"^(?P<name>.+)_(?P<kind>depth|ir)_u16le_(?P<h>\d+)x(?P<w>\d+)\.(?:bin|raw)$", re.IGNORECASE
)
_ADI_INTERLEAVED = re.compile(
    r"^(?P<name>.+)_interleaved_(?P<h>\d+)x(?P<w>\d+)\.(?:bin|raw)$", re.IGNORECASE
)


@dataclass(frozen=True)
class VendorName:
    """A vendor-named raw file: ``kind`` (``"depth"``, ``"ir"``, ``"interleaved"``), the
    ``<name>`` part, the frame size from the name and the camera profile."""

    kind: str
    name: str
    height: int
    width: int
    camera: str = "adtf3175"


def vendor_name(file_name) -> VendorName | None:
    """The vendor name pattern ``file_name`` matches (module docstring), else None."""
    base = os.path.basename(os.fspath(file_name))
    m = _ADI_PAIR.match(base)
    if m:
        return VendorName(m["kind"].lower(), m["name"], int(m["h"]), int(m["w"]))
    m = _ADI_INTERLEAVED.match(base)
    if m:
        return VendorName("interleaved", m["name"], int(m["h"]), int(m["w"]))
    return None


def vendor_partner(file_name) -> str | None:
    """The other file of a vendor pair (depth <-> IR), same case and suffix; None otherwise."""
    base = os.path.basename(os.fspath(file_name))
    m = _ADI_PAIR.match(base)
    if m is None:
        return None
    other = {"depth": "ir", "ir": "depth"}[m["kind"].lower()]
    if m["kind"].isupper():
        other = other.upper()
    return base[: m.start("kind")] + other + base[m.end("kind") :]


def _vendor(path, kinds: tuple[str, ...]) -> tuple[Path, VendorName]:
    p = Path(path)
    v = vendor_name(p.name)
    if v is None or v.kind not in kinds:
        raise ValueError(f"{p} is not named like an ADI {' / '.join(kinds)} file")
    return p, v


def _vendor_scale(depth_scale) -> float:
    return 1e-3 if depth_scale is None else check_scale(depth_scale)


def _vendor_raw(path, v: VendorName, what: str, dtype=None) -> np.ndarray:
    kw = {} if dtype is None else {"dtype": dtype}
    try:
        return read_raw_array(path, v.height, v.width, what=what, **kw)
    except FormatError as exc:
        raise FormatError(f"{exc} (the size {v.height} x {v.width} is from its name)") from exc


def adi_pair_frame_sets(depth_path, amplitude_path=None, depth_scale=None) -> list[FrameSet]:
    """The stored frames of an ADI vendor pair ``<name>_depth_u16le_<H>x<W>.bin`` (depth, mm)
    + ``<name>_ir_u16le_<H>x<W>.bin`` (``amplitude_path``, IR counts), the size from the name."""
    p, v = _vendor(depth_path, ("depth", "ir"))
    if v.kind != "depth" or amplitude_path is None:
        raise ValueError(
            f"{p}: pass the depth file of an ADI pair as depth_path and its "
            f"{vendor_partner(p.name) if v.kind == 'depth' else 'IR'} file as amplitude_path"
        )
    q = existing_file(amplitude_path, "amplitude")
    d, a = _vendor_raw(p, v, f"ADTF3175 {v.kind}"), _vendor_raw(q, v, "ADTF3175 IR")
    check_same_shape(d, a, f"{p} / {q}")
    return [FrameSet("", d, a, _vendor_scale(depth_scale), tuple(d.shape), v.camera)]


def adi_interleaved_frame_sets(path, amplitude_path=None, depth_scale=None) -> list[FrameSet]:
    """The stored depth and AB (the amplitude) of an ADI ``<name>_interleaved_<H>x<W>.bin``."""
    p, v = _vendor(path, ("interleaved",))
    if amplitude_path is not None:
        raise ValueError(f"{p} holds depth and AB interleaved; amplitude_path must be None")
    arr = _vendor_raw(p, v, f"ADTF3175 {v.kind}", ADI_INTERLEAVED_DTYPE)
    d, a = arr["depth"].astype(np.uint16), arr["ab"].astype(np.uint16)
    return [FrameSet("", d, a, _vendor_scale(depth_scale), tuple(d.shape), v.camera)]


def adi_interleaved_write_like(src: Path, dst: Path, depth: np.ndarray) -> None:
    """Write the interleaved file ``src`` back as ``dst`` with its depth replaced by ``depth``
    (stored mm, (T, H, W)); confidence and AB byte for byte."""
    out = np.fromfile(src, dtype=ADI_INTERLEAVED_DTYPE).reshape(depth.shape)
    out["depth"] = depth
    out.tofile(dst)
