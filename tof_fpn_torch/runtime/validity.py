r"""The one validity rule of the package (torch only, TorchScript-clean).

A pixel is **valid** when

* its depth is finite and ``> 0`` (NaN, ``+-inf``, ``0`` and negative depth are the usual
  "no measurement" codes of ToF cameras and of this package), and
* its amplitude, where one is given, is finite and ``>= 0`` (a NaN or negative amplitude is not a
  measurement either), and
* the caller's ``mask``, where one is given, is True.

Every stage, estimator and metric uses :func:`valid_mask`; an invalid pixel is never used as data
and every stage returns it unchanged (NaN stays NaN, 0 stays 0, -1 stays -1).
"""

from __future__ import annotations

import math

import torch

__all__ = ["all_valid", "valid_mask", "valid_range"]


def valid_mask(
    depth: torch.Tensor,
    amplitude: torch.Tensor | None = None,
    mask: torch.Tensor | None = None,
    signed: bool = False,
) -> torch.Tensor:
    """Boolean map of valid pixels: depth finite and > 0, amplitude finite and >= 0, and ``mask``.

    Args:
        depth: (B, C, H, W) floating depth.
        amplitude: optional amplitude broadcastable to ``depth`` (usually (B, 1, H, W)).
        mask: optional bool map broadcastable to ``depth`` (True = usable).
        signed: the data are not depth but a signed quantity (a residual, a natural image given to
            a denoiser): then only NaN and +-inf are invalid.

    Returns:
        Bool tensor of the broadcast shape.

    Example:
        >>> d = torch.tensor([[[[1.0, 0.0, -1.0, float("nan"), 2.0]]]])
        >>> a = torch.tensor([[[[5.0, 5.0, 5.0, 5.0, float("nan")]]]])
        >>> valid_mask(d, a)
        tensor([[[[ True, False, False, False, False]]]])
    """
    if signed:
        valid = torch.isfinite(depth)
    else:
        valid = (depth > 0) & (depth < math.inf)  # NaN fails both comparisons
    if amplitude is not None:
        valid = valid & (amplitude >= 0) & (amplitude < math.inf)
    if mask is not None:
        valid = valid & mask.to(torch.bool)
    return valid


def all_valid(depth: torch.Tensor) -> bool:
    """True when every depth value is finite and > 0: one reduction, no mask allocated.

    ``min > 0`` and ``max < inf`` (NaN fails both) is the rule of :func:`valid_mask` for depth. For
    float32 in eager mode the same test runs on the bit patterns, an integer min/max without NaN
    logic: a positive finite float32 is exactly ``0 < bits < 0x7F800000`` (the bits of ``+inf``),
    and the sign bit makes every negative value (and ``-0``) a negative integer.
    """
    if depth.numel() == 0:
        return True
    if depth.dtype == torch.float32 and not torch.jit.is_scripting():
        lo, hi = torch.aminmax(depth.view(torch.int32))  # TorchScript reads view(int) as a shape
        return bool(lo > 0) and bool(hi < 0x7F800000)
    lo, hi = torch.aminmax(depth)
    return bool(lo > 0) and bool(hi < math.inf)


def valid_range(depth: torch.Tensor, zeros: bool = False) -> tuple[float, float] | None:
    """``(min, max)`` of ``depth`` when every value is valid (finite, > 0), else None: the same
    one reduction as :func:`all_valid` (for float32 in eager mode on the bit patterns, whose order
    is the order of the values for positive floats). With ``zeros`` (float32, eager mode) also
    ``(0.0, max)`` when the invalid values are all ``+0.0``: no negative number, nor ``-0.0``, no
    NaN, no infinity."""
    if depth.numel() == 0:
        return None
    if depth.dtype == torch.float32 and not torch.jit.is_scripting():
        lo, hi = torch.aminmax(depth.view(torch.int32))
        if (bool(lo > 0) or (zeros and bool(lo == 0))) and bool(hi < 0x7F800000):
            pair = torch.stack([lo, hi]).view(torch.float32).tolist()
            return float(pair[0]), float(pair[1])
        return None
    lo, hi = torch.aminmax(depth.detach())
    if bool(lo > 0) and bool(hi < math.inf):
        return float(lo), float(hi)
    return None
