r"""How much column stripe a frame has, measured so that white noise does not count (torch).

**Column-stripe energy.** Let ``HP`` be the depth minus its mean over ``width`` neighbouring valid
pixels of the same row (a horizontal high-pass; scene structure wider than ``width`` columns does
not enter), and ``p_top(x)``, ``p_bot(x)`` the means of ``HP`` down column ``x`` over the pixels
of a region in the top and in the bottom part of the rows. The energy is their covariance over the
columns,

    ``E = mean_x (p_top(x) - mean p_top) (p_bot(x) - mean p_bot)``   (depth units squared).

A column offset is the same in both parts and adds its variance to ``E``; white noise and
anything confined to one part are independent between them and add nothing in expectation. ``E``
can be negative (no common pattern; e.g. after a correction estimated from all rows, whose noise
enters both parts with opposite signs, ``E`` falls about ``(var p_top + var p_bot) / 4`` below
zero). The region should leave out strong scene structure (:func:`structure_mask`).

**Low-pass change.** The RMS over the valid pixels of the change ``after - before`` averaged over
``size x size`` valid pixels: how much a correction moves the depth at scales above ``size``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from ..runtime.noise import mad_to_sigma
from ..runtime.validity import valid_mask

__all__ = [
    "StripeEnergy",
    "column_stripe_energy",
    "lowpass_change",
    "quiet_mask",
    "row_highpass",
    "structure_mask",
]


def _check(depth: torch.Tensor, name: str = "depth") -> None:
    if not isinstance(depth, torch.Tensor) or depth.dim() != 4 or not depth.is_floating_point():
        raise ValueError(
            f"{name} must be a floating (B, C, H, W) tensor, got "
            f"{getattr(depth, 'shape', type(depth))}"
        )


def _box_along_rows(x: torch.Tensor, width: int) -> torch.Tensor:
    k = torch.ones(1, 1, 1, width, dtype=x.dtype, device=x.device)
    b, c, h, w = x.shape
    y = F.conv2d(x.reshape(b * c, 1, h, w), k, padding=(0, width // 2))
    return y.reshape(b, c, h, w)


def row_highpass(
    depth: torch.Tensor, width: int = 9, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """``depth`` minus the mean of the valid pixels within ``width // 2`` columns in its row (0 at
    invalid pixels). ``width``: odd int >= 3."""
    _check(depth)
    if isinstance(width, bool) or not isinstance(width, int) or width < 3 or width % 2 == 0:
        raise ValueError(f"width must be an odd int >= 3, got {width!r}")
    v = valid_mask(depth) if valid is None else valid
    x = torch.where(v, depth, 0.0).double()
    num = _box_along_rows(x, width)
    den = _box_along_rows(v.double(), width)
    hp = x - num / den.clamp_min(1.0)
    return torch.where(v, hp, 0.0).to(depth.dtype)


def structure_mask(
    depth: torch.Tensor, threshold: float, width: int = 15, dilate: int = 6
) -> torch.Tensor:
    """Valid pixels away from strong scene structure: ``|row_highpass(depth, width)| >
    threshold`` (depth units) dilated by ``dilate`` pixels is left out."""
    _check(depth)
    v = valid_mask(depth)
    strong = (row_highpass(depth, width, v).abs() > threshold).to(depth.dtype)
    if dilate > 0:
        b, c, h, w = strong.shape
        k = 2 * dilate + 1
        strong = F.max_pool2d(strong.reshape(b * c, 1, h, w), k, 1, dilate).reshape(b, c, h, w)
    return v & (strong == 0)


def quiet_mask(depth: torch.Tensor, sigmas: float = 6.0, width: int = 15) -> torch.Tensor:
    """:func:`structure_mask` at ``sigmas`` robust standard deviations (``1.4826`` times the
    median absolute value over the valid pixels) of the row high-pass itself: the scale includes
    the noise *and* any stripes, so stripes far above the noise stay in the region and only scene
    structure (edges, thin objects: outliers of the high-pass) is left out. A threshold from the
    noise alone would leave out every pixel of a frame whose stripes are many noise sigmas."""
    _check(depth)
    v = valid_mask(depth)
    hp = row_highpass(depth, width, v)
    if not bool(v.any()):
        return v
    scale = float(mad_to_sigma(hp[v].abs().median().double(), 1))
    return structure_mask(depth, sigmas * scale, width) if scale > 0 else v


@dataclass
class StripeEnergy:
    """Result of :func:`column_stripe_energy`, one entry per image (B * C,) unless noted.

    Attributes:
        covariance: ``E`` (depth units squared).
        correlation: the correlation coefficient of the two profiles.
        spread: the standard deviation of the mean profile ``(p_top + p_bot) / 2`` (counts noise).
        top, bottom: (B * C, W) profiles (NaN at columns not used).
        columns: (B * C,) number of columns used.
    """

    covariance: torch.Tensor
    correlation: torch.Tensor
    spread: torch.Tensor
    top: torch.Tensor
    bottom: torch.Tensor
    columns: torch.Tensor


def column_stripe_energy(
    depth: torch.Tensor,
    region: torch.Tensor | None = None,
    width: int = 9,
    split: int | None = None,
    min_rows: int = 16,
) -> StripeEnergy:
    """Column-stripe energy (module docstring) of every image of ``depth`` (B, C, H, W).

    Args:
        region: bool (B, C, H, W) pixels to use (default: the valid ones); invalid pixels never
            count.
        width: the high-pass width (odd int >= 3).
        split: first row of the bottom part (default ``H // 2``).
        min_rows: a column is used when it has at least this many region pixels in each part.
    """
    _check(depth)
    v = valid_mask(depth)
    m = v if region is None else (region & v)
    hp = row_highpass(depth, width, v).double()
    b, c, h, w = depth.shape
    s = h // 2 if split is None else int(split)
    if not 0 < s < h:
        raise ValueError(f"split must lie in (0, H = {h}), got {split!r}")
    hp, m = hp.reshape(b * c, h, w), m.reshape(b * c, h, w)
    profiles, counts = [], []
    for rows in (slice(0, s), slice(s, h)):
        mm = m[:, rows].double()
        n = mm.sum(1)
        profiles.append((hp[:, rows] * mm).sum(1) / n.clamp_min(1.0))
        counts.append(n)
    use = (counts[0] >= min_rows) & (counts[1] >= min_rows)
    k = use.sum(1).double()
    nan = torch.full_like(profiles[0], float("nan"))
    top, bot = (torch.where(use, p, nan) for p in profiles)
    mt = torch.where(use, top, 0.0).sum(1, keepdim=True) / k.clamp_min(1.0)[:, None]
    mb = torch.where(use, bot, 0.0).sum(1, keepdim=True) / k.clamp_min(1.0)[:, None]
    dt, db = torch.where(use, top - mt, 0.0), torch.where(use, bot - mb, 0.0)
    cov = (dt * db).sum(1) / k.clamp_min(1.0)
    vt, vb = (dt * dt).sum(1) / k.clamp_min(1.0), (db * db).sum(1) / k.clamp_min(1.0)
    corr = cov / torch.sqrt(vt * vb).clamp_min(1e-300)
    mean = 0.5 * (dt + db)
    spread = torch.sqrt((mean * mean).sum(1) / k.clamp_min(1.0))
    return StripeEnergy(cov, corr, spread, top, bot, k)


def lowpass_change(
    before: torch.Tensor, after: torch.Tensor, size: int = 15, region: torch.Tensor | None = None
) -> torch.Tensor:
    """RMS (per image) over the valid pixels of ``before`` (and ``region``) of ``after - before``
    averaged over ``size x size`` valid pixels."""
    _check(before, "before")
    _check(after, "after")
    if before.shape != after.shape:
        raise ValueError(
            f"before and after must have the same shape, got {list(before.shape)} and "
            f"{list(after.shape)}"
        )
    v = valid_mask(before)
    m = v if region is None else (region & v)
    b, c, h, w = before.shape
    d = torch.where(v, after.double() - before.double(), 0.0).reshape(b * c, 1, h, w)
    vv = v.double().reshape(b * c, 1, h, w)
    num = F.avg_pool2d(d, size, 1, size // 2, count_include_pad=True)
    den = F.avg_pool2d(vv, size, 1, size // 2, count_include_pad=True)
    low = (num / den.clamp_min(1e-12))[..., :h, :w].reshape(b * c, h, w)
    mm = m.reshape(b * c, h, w).double()
    return torch.sqrt((low * low * mm).sum((1, 2)) / mm.sum((1, 2)).clamp_min(1.0))
