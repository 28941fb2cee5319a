r"""A per-pixel parameter for filters that take one value per image (kornia's ``sigma_color`` of
the bilateral filters, ``eps`` of the guided filter): run the filter at a few levels and
interpolate per pixel.

The levels are log-spaced from the smallest to the largest value of the map over the valid pixels
of each image, at most a factor ``ratio`` apart (``ratio = 1.25`` by default: at most 11 levels for
a 10x range); every level is one batch entry of a single call of the wrapped filter, so each
level's output is exactly the filter's. A pixel whose value lies between two levels gets the
linear interpolation of the two outputs in ``log(value)``; a pixel at a level gets that level's
output. An image whose map is constant has one level: the wrapped filter's own result.
"""

from __future__ import annotations

import math

import torch

__all__ = ["LEVEL_RATIO", "MAX_LEVELS", "blend", "check_levels", "levels"]

#: Default ``ratio`` of the kornia-based denoisers (:mod:`.bilateral`, :mod:`.guided`): the noise
#: levels of an image's filter bank are at most this factor apart ...
LEVEL_RATIO: float = 1.25
#: ... and at most this many (default ``max_levels``).
MAX_LEVELS: int = 12


def check_levels(ratio: float, max_levels: int) -> None:
    """``ratio`` > 1 (finite) and ``max_levels`` >= 1."""
    if not (ratio > 1.0 and ratio < float("inf")) or max_levels < 1:
        raise ValueError(f"ratio must be > 1 and max_levels >= 1, got {ratio}, {max_levels}")


def levels(value: torch.Tensor, valid: torch.Tensor, ratio: float, max_levels: int) -> torch.Tensor:
    """(B, L) log-spaced levels spanning ``value`` (B, 1, H, W) over ``valid``; L is the same for
    the batch (at least 1, at most ``max_levels``)."""
    check_levels(ratio, max_levels)
    B = value.shape[0]
    big = torch.full_like(value, math.inf)
    lo = torch.where(valid, value, big).flatten(1).amin(1)
    hi = torch.where(valid, value, -big).flatten(1).amax(1)
    ok = torch.isfinite(lo) & (lo > 0)
    lo = torch.where(ok, lo, torch.ones_like(lo))
    hi = torch.where(ok, torch.maximum(hi, lo), lo)
    span = float((hi / lo).max())
    n = 1
    if span > 1.0 + 1e-6:
        n = min(max_levels, int(math.ceil(math.log(span) / math.log(ratio) - 1e-9)) + 1)
        n = max(n, 2)
    t = torch.linspace(0.0, 1.0, n, dtype=value.dtype, device=value.device).reshape(1, n)
    if n == 1:
        t = torch.zeros(1, 1, dtype=value.dtype, device=value.device)
    out = lo.reshape(B, 1) * torch.pow((hi / lo).reshape(B, 1), t)
    out[:, -1] = hi  # the ends exactly
    out[:, 0] = lo
    return out


def blend(results: torch.Tensor, lv: torch.Tensor, value: torch.Tensor) -> torch.Tensor:
    """Per-pixel interpolation in ``log(value)`` of ``results`` (B, L, C, H, W) computed at the
    levels ``lv`` (B, L); ``value`` (B, 1, H, W), clamped to the levels' range."""
    B, L = lv.shape[0], lv.shape[1]
    if L == 1:
        return results[:, 0]
    logl = lv.log()  # (B, L)
    v = value.clamp_min(1e-30).log()  # (B, 1, H, W)
    v = torch.minimum(torch.maximum(v, logl[:, :1, None, None]), logl[:, -1:, None, None])
    # index of the level at or below v: count of levels <= v, minus one
    i = (logl[:, 1:-1, None, None] <= v).sum(1, keepdim=True)  # (B, 1, H, W), 0 .. L - 2
    lo = torch.gather(logl, 1, i.flatten(1)).reshape(v.shape)
    hi = torch.gather(logl, 1, (i + 1).flatten(1)).reshape(v.shape)
    frac = ((v - lo) / (hi - lo).clamp_min(1e-30)).clamp(0.0, 1.0)
    C = results.shape[2]
    idx = i.unsqueeze(1).expand(B, 1, C, v.shape[2], v.shape[3])
    r0 = torch.gather(results, 1, idx)[:, 0]
    r1 = torch.gather(results, 1, idx + 1)[:, 0]
    return r0 + frac * (r1 - r0)
