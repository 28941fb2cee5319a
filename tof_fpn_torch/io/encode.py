"""Cleaned depth back into a file's own stored values: :func:`encode_depth`, with nearest or
dithered rounding for integer files (what ``tof-fpn clean`` writes).

A uint16-mm file cannot hold a correction of 0.3 mm by rounding to the nearest millimetre: every
pixel rounds back to its input value, and the correction is lost. Dithered rounding rounds each
pixel up with probability equal to its fractional part, so the expected stored value is the
corrected one and every mean over many pixels (a column's, a region's) keeps the correction; the
price is a rounding noise of variance ``f (1 - f)`` per pixel (1/6 unit^2 on average) against
nearest rounding's 1/12, white and independent of the scene.
"""

from __future__ import annotations

import zlib

import numpy as np
import torch

from ._common import FrameSet, check_scale, depth_from_stored

__all__ = ["ROUNDING", "encode_depth"]


#: how integer outputs round (see :func:`encode_depth`)
ROUNDING = ("nearest", "dither")


def encode_depth(
    fs: FrameSet,
    depth: torch.Tensor,
    rounding: str = "nearest",
    output_scale: float | None = None,
) -> tuple[np.ndarray, int]:
    """Cleaned depth (T, 1, H, W) metres -> the stored array (T, H, W) in ``fs.depth``'s dtype.

    Every pixel invalid in the input (:func:`valid_mask` of the stored depth and amplitude) keeps
    its stored value bit for bit; so does a valid pixel the cleaning did not change (equal to the
    input decoded by :func:`frame_set_tensors`). A changed valid pixel gets ``stored +
    change / scale`` and stays valid: floating files cast; integer files round and clamp to
    ``[1, max]`` (0 is the invalid code). A non-finite result (which the run-time stages never
    give) keeps the input value. A valid pixel a stage invalidated on purpose (cleaned depth
    exactly 0, as ``tof-fpn clean --flying invalidate`` does) is written as 0.

    Args:
        fs: the frame set as read.
        depth: the cleaned depth, metres (NaN where invalid).
        rounding: integer files: ``"nearest"``, or ``"dither"``: up with probability equal to the
            fractional part (a uniform dither, from a generator seeded by the frame's own stored
            bytes: the same input gives the same bytes), so every mean over many pixels keeps the
            correction that nearest rounding loses below half a unit (its noise variance is
            ``f (1 - f)``, 1/6 unit^2 on average, against 1/12).
        output_scale: integer files: metres per unit of the output (None: the input's). Every
            valid pixel is converted then, unchanged ones by the same rule without the change.

    Returns:
        the array and the number of valid pixels clamped or kept because of a non-finite value.
    """
    if rounding not in ROUNDING:
        raise ValueError(f"rounding must be one of {list(ROUNDING)}, got {rounding!r}")
    stored = fs.depth
    integer = stored.dtype.kind in "ui"
    if output_scale is not None:
        output_scale = check_scale(output_scale, "output_scale")
    with np.errstate(invalid="ignore"):  # valid_mask's rule on the stored values (scale > 0)
        valid = (stored > 0) & np.isfinite(stored)
        valid &= (fs.amplitude >= 0) & np.isfinite(fs.amplitude)
    before = depth_from_stored(stored, fs.depth_scale)[:, 0].numpy().astype(np.float64)
    cleaned = depth.detach().cpu().double()[:, 0].numpy()
    dropped = valid & (cleaned == 0.0)  # invalidated by a stage (the flying-pixel stage)
    change = cleaned - before  # 0 where unchanged
    finite = np.isfinite(change)
    change = np.where(finite, change, 0.0)
    if integer:
        scale = fs.depth_scale if output_scale is None else output_scale
        units = (stored.astype(np.float64) * fs.depth_scale + change) / scale
        if output_scale is None:  # exact where unchanged (no round trip through metres)
            units = np.where(change == 0.0, stored.astype(np.float64), units)
        r = _dither(units, stored) if rounding == "dither" else np.rint(units)
        hi = float(np.iinfo(stored.dtype).max)
        moved = (r < 1) | (r > hi)
        new = np.clip(r, 1, hi).astype(stored.dtype)
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            new = np.where(change == 0.0, stored, (before + change) / fs.depth_scale)
            new = new.astype(stored.dtype)
        moved = ~(np.isfinite(new) & (new > 0))
    keep = ~valid | ~finite | (moved & (not integer))
    out = np.where(dropped, 0, np.where(keep, stored, new)).astype(stored.dtype)
    return out, int((valid & ~dropped & (~finite | moved)).sum())


def _dither(units: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """``floor(units + u)``, ``u`` uniform in [0, 1), seeded per frame by the stored bytes."""
    out = np.empty_like(units)
    for t in range(units.shape[0]):
        seed = zlib.crc32(np.ascontiguousarray(stored[t]).tobytes())
        u = np.random.default_rng(seed).random(units.shape[1:])
        out[t] = np.floor(units[t] + u)
    return out
