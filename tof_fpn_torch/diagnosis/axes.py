"""The axes physics acts on, as per-pixel bin labels (H, W) int64 (-1: not binned).

``column``, ``row`` (one bin each), ``depth`` (true scene depth, quantile bins), ``depth_mod``
(true depth modulo the cyclic-error period ``c_L / (2 f N)``; only with a known frequency),
``amplitude`` (predicted noise-free amplitude, quantile bins), ``radius`` (from the frame centre,
in half-diagonals), ``edge`` (distance in px to the nearest depth edge of the scene), ``raw``
(predicted largest correlation sample ``B + A``, quantile bins); ``pixels``: one bin per pixel
(the sum of squared standardised residuals: EMVA 1288's spatial non-uniformity). The frame axis is handled on the frames themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from .. import constants as K

__all__ = ["Axis", "axes", "edge_distance"]

_QBINS = 12
_EDGE_BINS = (0, 1, 2, 3, 5, 8, 10**9)


@dataclass
class Axis:
    """Bin labels (H, W), the value of each bin's centre and its unit, and bin edges for text."""

    name: str
    labels: torch.Tensor
    centres: torch.Tensor
    unit: str
    edges: list


def _quantile_bins(x: torch.Tensor, mask: torch.Tensor, nb: int = _QBINS):
    q = torch.quantile(x[mask], torch.linspace(0, 1, nb + 1, dtype=x.dtype))
    q = torch.unique(q)
    if q.numel() < 2:  # one value: one bin
        q = torch.cat([q, q + 1.0])
    lab = torch.bucketize(x, q[1:-1].contiguous())
    lab = torch.where(mask, lab, torch.full_like(lab, -1))
    cen = 0.5 * (q[1:] + q[:-1])
    return lab, cen, q.tolist()


def _uniform_bins(x: torch.Tensor, mask: torch.Tensor, lo: float, hi: float, nb: int):
    e = torch.linspace(lo, hi, nb + 1, dtype=torch.float64)
    lab = torch.bucketize(x, e[1:-1].contiguous())
    lab = torch.where(mask, lab, torch.full_like(lab, -1))
    return lab, 0.5 * (e[1:] + e[:-1]), e.tolist()


def edge_distance(depth: torch.Tensor, known: torch.Tensor, limit: int = 12) -> torch.Tensor:
    """Distance (px, chessboard, capped at ``limit``) to the nearest depth edge: a jump between
    4-neighbours above 2 % of the depth (or at unknown pixels)."""
    d = depth
    jump = torch.zeros_like(d, dtype=torch.bool)
    dx = (d[:, 1:] - d[:, :-1]).abs() > 0.02 * torch.minimum(d[:, 1:], d[:, :-1])
    dy = (d[1:] - d[:-1]).abs() > 0.02 * torch.minimum(d[1:], d[:-1])
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:] |= dy
    jump[:-1] |= dy
    dist = torch.full_like(d, float(limit))
    cur = jump.to(torch.float64)[None, None]
    for k in range(limit):
        dist = torch.where((cur[0, 0] > 0) & (dist > k), torch.full_like(d, float(k)), dist)
        cur = F.max_pool2d(cur, 3, 1, 1)
    return dist


def axes(obs, pred, mask: torch.Tensor) -> dict[str, Axis]:
    """Every axis for the pixels of ``mask`` (the others get label -1)."""
    h, w = obs.shape
    out = {}
    xx = torch.arange(w).view(1, w).expand(h, w)
    yy = torch.arange(h).view(h, 1).expand(h, w)
    out["column"] = Axis(
        "column",
        torch.where(mask, xx, -1),
        torch.arange(w, dtype=torch.float64),
        "px",
        [],
    )
    out["row"] = Axis(
        "row", torch.where(mask, yy, -1), torch.arange(h, dtype=torch.float64), "px", []
    )
    lab, cen, e = _quantile_bins(obs.scene_depth, mask)
    out["depth"] = Axis("depth", lab, cen, "m", e)
    if obs.frequency is not None:
        period = K.SPEED_OF_LIGHT_AIR / (2.0 * obs.frequency * obs.n_phases)
        frac = torch.remainder(obs.scene_depth, period) / period
        lab, cen, e = _uniform_bins(frac, mask, 0.0, 1.0, _QBINS)
        out["depth_mod"] = Axis("depth_mod", lab, cen * period, "m", [x * period for x in e])
    lab, cen, e = _quantile_bins(pred.a0.detach(), mask)
    out["amplitude"] = Axis("amplitude", lab, cen, obs.amplitude_unit, e)
    half = math.hypot((h - 1) / 2, (w - 1) / 2)
    r = torch.sqrt(((xx - (w - 1) / 2.0) ** 2 + (yy - (h - 1) / 2.0) ** 2).double()) / half
    lab, cen, e = _uniform_bins(r, mask, 0.0, 1.0, 10)
    out["radius"] = Axis("radius", lab, cen, "half-diagonals", e)
    dist = edge_distance(obs.scene_depth, obs.known)
    lab = torch.bucketize(dist, torch.tensor(_EDGE_BINS[1:-1], dtype=torch.float64), right=True)
    lab = torch.where(mask, lab, -1)
    cen = torch.tensor([0, 1, 2, 3.5, 6, 10], dtype=torch.float64)
    out["edge"] = Axis("edge", lab, cen, "px", list(_EDGE_BINS))
    raw = (pred.offset + pred.a0).detach()
    lab, cen, e = _quantile_bins(raw, mask)
    out["raw"] = Axis("raw", lab, cen, obs.amplitude_unit, e)
    idx = torch.arange(h * w).view(h, w)
    out["pixels"] = Axis("pixels", torch.where(mask, idx, -1), idx.reshape(-1).double(), "", [])
    return out
