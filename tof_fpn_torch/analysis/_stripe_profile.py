"""Steps 1-3 of :func:`~tof_fpn_torch.analysis.estimate_stripes` (see :mod:`.stripes`): the pixel
weights and the outlier-free, high-passed profile of the lines (torch, kornia)."""

from __future__ import annotations

import math

import kornia.filters as KF
import torch
import torch.nn.functional as F

from ..runtime.noise import clipped_scale, mad_to_sigma

__all__: list[str] = []


def _weights(
    depth: torch.Tensor, amplitude: torch.Tensor | None, valid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(d, w)`` (B, H, W) float64: the depth (0 where invalid) and the weight of each valid pixel,
    ``1 / (1 + A / median A)`` (module docstring, step 1; 1 without amplitude, 0 where invalid)."""
    d = torch.where(valid, depth[:, 0].double(), torch.zeros_like(depth[:, 0].double()))
    if amplitude is not None:
        a = torch.where(valid, amplitude[:, 0].double(), torch.zeros_like(d))
        med = float(a[valid].median()) or 1.0
        w = torch.where(valid, 1.0 / (1.0 + a / med), torch.zeros_like(d))
    else:
        w = valid.to(d.dtype)
    return d, w


def _profile(
    d: torch.Tensor, valid: torch.Tensor, w: torch.Tensor, smooth: int
) -> tuple[torch.Tensor, torch.Tensor, float]:
    """The weighted, outlier-free mean of the high-passed lines (profile axis last), the columns
    it has, and the per-pixel noise sigma."""
    v = valid.to(d.dtype)
    size = (1, 2 * smooth + 1)  # kornia's box filter along each line over the valid samples
    num = KF.box_blur((d * v).unsqueeze(1), size, border_type="constant").squeeze(1)
    den = KF.box_blur(v.unsqueeze(1), size, border_type="constant").squeeze(1)
    r = torch.where(valid, d - num / den.clamp_min(0.5 / (2 * smooth + 1)), torch.zeros_like(d))
    sigma = float(mad_to_sigma(r[valid].abs().median(), 1)) if bool(valid.any()) else 0.0
    keep = valid & (r.abs() <= 4.0 * sigma) if sigma > 0 else valid
    # pixels within the box's reach of a scene edge (a central difference beyond 4 robust sigmas
    # of all central differences) carry the edge's residual: leave them out
    grad = torch.zeros_like(d)
    grad[..., 1:-1] = (d[..., 2:] - d[..., :-2]).abs()
    pair = torch.zeros_like(valid)
    pair[..., 1:-1] = valid[..., 2:] & valid[..., :-2]
    if bool(pair.any()):
        # a clipped mean, not a MAD: strong stripes at 2 pi / 3 make the central differences
        # two-valued (0 in a third of the columns), and a MAD of 0 made every stripe an edge
        g_sigma = float(clipped_scale(grad[pair]))
        edge = (pair & (grad > 4.0 * g_sigma)).to(d.dtype).unsqueeze(1)
        near = F.max_pool2d(edge, (1, 2 * smooth + 1), 1, (0, smooth)).squeeze(1) > 0
        keep = keep & ~near
    wk = torch.where(keep, w, torch.zeros_like(w))
    wsum = wk.sum((0, 1))  # over frames and lines
    p = (wk * r).sum((0, 1)) / wsum.clamp_min(1e-30)
    has = wsum > 0
    if bool(has.any()):
        # columns where the profile is an outlier (what is left of a vertical scene edge or a
        # thin object spanning the frame, broadband) are left out of the spectrum. The scale is a
        # clipped mean |p - mean| (not a MAD: a stripe at pi makes the profile two-valued, and
        # the MAD of a two-valued profile is 0)
        dev = (p - p[has].mean()).abs()
        has = has & (dev <= 5.0 * float(clipped_scale(dev[has])))
    p = torch.where(has, p - p[has].mean() if bool(has.any()) else p, torch.zeros_like(p))
    # r = d - box(d): white noise keeps (1 - 1/n) of its variance
    noise = sigma / math.sqrt(1.0 - 1.0 / (2 * smooth + 1))
    return p, has, noise
