"""The record's measures as they were first written: box filters as dense ``conv2d`` kernels, the
dilation as a ``max_pool2d``, the low-pass as an ``avg_pool2d``, every mask recomputed where it is
used. Kept as the reference that the fast functions of
:mod:`tof_fpn_torch.analysis.stripe_energy` and the record of ``tof-fpn clean``
(:mod:`tof_fpn_torch.clean.measure`) must equal up to float rounding. Slow: for tests only.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from tof_fpn_torch.denoise import estimate_sigma
from tof_fpn_torch.runtime.noise import mad_to_sigma
from tof_fpn_torch.runtime.validity import valid_mask


def _box_along_rows(x: torch.Tensor, width: int) -> torch.Tensor:
    k = torch.ones(1, 1, 1, width, dtype=x.dtype, device=x.device)
    b, c, h, w = x.shape
    y = F.conv2d(x.reshape(b * c, 1, h, w), k, padding=(0, width // 2))
    return y.reshape(b, c, h, w)


def row_highpass(depth, width=9, valid=None):
    v = valid_mask(depth) if valid is None else valid
    x = torch.where(v, depth, 0.0).double()
    num = _box_along_rows(x, width)
    den = _box_along_rows(v.double(), width)
    hp = x - num / den.clamp_min(1.0)
    return torch.where(v, hp, 0.0).to(depth.dtype)


def structure_mask(depth, threshold, width=15, dilate=6):
    v = valid_mask(depth)
    strong = (row_highpass(depth, width, v).abs() > threshold).to(depth.dtype)
    if dilate > 0:
        b, c, h, w = strong.shape
        k = 2 * dilate + 1
        strong = F.max_pool2d(strong.reshape(b * c, 1, h, w), k, 1, dilate).reshape(b, c, h, w)
    return v & (strong == 0)


def quiet_mask(depth, sigmas=6.0, width=15):
    v = valid_mask(depth)
    hp = row_highpass(depth, width, v)
    if not bool(v.any()):
        return v
    scale = float(mad_to_sigma(hp[v].abs().median().double(), 1))
    return structure_mask(depth, sigmas * scale, width) if scale > 0 else v


def column_stripe_energy(depth, region=None, width=9, split=None, min_rows=16):
    """(covariance, correlation, spread, top, bottom, columns) as in the library."""
    v = valid_mask(depth)
    m = v if region is None else (region & v)
    hp = row_highpass(depth, width, v).double()
    b, c, h, w = depth.shape
    s = h // 2 if split is None else int(split)
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
    return cov, corr, spread, top, bot, k


def lowpass_change(before, after, size=15, region=None):
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


def frame_record(before: torch.Tensor, after: torch.Tensor) -> dict:
    """The per-frame record of ``tof-fpn clean`` as first written (one (1, 1, H, W) frame)."""
    thin = min(before.shape[-2:]) < 2
    valid = valid_mask(before)
    x = torch.where(valid, before, 0.0).double()
    noise = None
    if bool(valid.any()) and not thin:
        noise = 1e3 * float(estimate_sigma(x, valid=valid).mean())
    same = (before == after) | (before.isnan() & after.isnan())
    both = valid & valid_mask(after)
    moved = None
    if bool(both.any()):
        nan = torch.full_like(before, float("nan"))
        b, a = torch.where(both, before, nan), torch.where(both, after, nan)
        moved = 1e3 * float(lowpass_change(b, a))
    stripes = {}
    for name, transpose in (("columns", False), ("rows", True)):
        b, a = (before, after) if not transpose else (before.mT, after.mT)
        if thin:
            stripes[name] = dict.fromkeys(("before_mm2", "after_mm2", "z"))
            continue
        quiet = quiet_mask(b)
        eb, ea = column_stripe_energy(b, quiet), column_stripe_energy(a, quiet)
        n, r = float(eb[5][0]), float(eb[1][0])
        stripes[name] = {
            "before_mm2": 1e6 * float(eb[0][0]),
            "after_mm2": 1e6 * float(ea[0][0]),
            "z": r * math.sqrt(n) if n > 0 and math.isfinite(r) else 0.0,
        }
    return {
        "noise_mm": noise,
        "stripes": stripes,
        "lowpass_change_mm": moved,
        "changed": float((~same & valid).sum()) / max(int(valid.sum()), 1),
    }
