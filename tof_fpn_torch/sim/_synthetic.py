"""The objects of :func:`~tof_fpn_torch.sim.synthetic_scene` (a Fig.-7-like scene): a slanted
wall, then rectangles, a wedge, a hemisphere, rings, a Siemens star, thin bars, a grating and a
dark object, each drawn with the scene's generator in this order (the draws make the scene)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__: list[str] = []


def _u(g: torch.Generator, low: float = 0.0, high: float = 1.0) -> float:
    return low + (high - low) * float(torch.rand((), generator=g, dtype=torch.float64))


@dataclass
class _Canvas:
    """What every object of a synthetic scene is drawn with: the pixel grid, the depth and
    amplitude ranges and the generator (whose draws, in drawing order, make the scene)."""

    yy: torch.Tensor
    xx: torch.Tensor
    g: torch.Generator
    dmin: float
    dmax: float
    amax: float

    @property
    def s(self) -> int:
        return min(self.yy.shape[0], self.yy.shape[1])

    @property
    def span(self) -> float:
        return self.dmax - self.dmin

    def material(self) -> float:
        return self.amax * _u(self.g, 0.05, 1.0)


def _one_synthetic(
    h: int, w: int, g: torch.Generator, dmin: float, dmax: float, amax: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """One Fig.-7-like scene (float64 CPU): depth in [dmin, dmax], amplitude in [0, amax]."""
    yy, xx = torch.meshgrid(
        torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij"
    )
    c = _Canvas(yy, xx, g, dmin, dmax, amax)
    depth, amp = _background(c)
    for draw in (_rectangles, _wedge, _hemisphere, _rings, _star, _bars, _grating, _dark_object):
        depth, amp = draw(c, depth, amp)
    return depth.clamp(dmin, dmax), amp.clamp(0.0, amax)


def _background(c: _Canvas) -> tuple[torch.Tensor, torch.Tensor]:
    """A slanted, slightly curved wall from far (top) to mid range (bottom); dim, smooth."""
    yy, xx, g, span, dmax, amax = c.yy, c.xx, c.g, c.span, c.dmax, c.amax
    h, w = yy.shape
    tilt = _u(g, 0.25, 0.45)
    depth = dmax - tilt * span * (yy / (h - 1)) - 0.05 * span * ((xx / (w - 1) - 0.5) ** 2)
    amp = amax * (0.12 + 0.10 * (xx / (w - 1))) + 0.0 * yy  # dim, smooth
    amp = amp * (1.0 + 0.15 * torch.cos(2 * math.pi * yy / _u(g, 25, 45)))
    return depth, amp


def _rectangles(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """Fronto-parallel rectangles (edges)."""
    yy, xx, g, s, span, dmin, dmax = c.yy, c.xx, c.g, c.s, c.span, c.dmin, c.dmax
    h, w = yy.shape
    for _ in range(5):
        rh, rw = int(_u(g, 0.12, 0.3) * s), int(_u(g, 0.12, 0.3) * s)
        y0, x0 = int(_u(g, 0, h - rh)), int(_u(g, 0, w - rw))
        m = (yy >= y0) & (yy < y0 + rh) & (xx >= x0) & (xx < x0 + rw)
        depth = torch.where(
            m, torch.full_like(depth, _u(g, dmin + 0.1 * span, dmax - 0.2 * span)), depth
        )
        amp = torch.where(m, torch.full_like(amp, c.material()), amp)
    return depth, amp


def _wedge(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """A wedge (linear depth ramp) with a striped texture in amplitude."""
    yy, xx, g, s, span, dmin = c.yy, c.xx, c.g, c.s, c.span, c.dmin
    h, w = yy.shape
    y0, x0 = int(_u(g, 0, 0.6 * h)), int(_u(g, 0, 0.6 * w))
    m = (yy >= y0) & (yy < y0 + 0.35 * s) & (xx >= x0) & (xx < x0 + 0.3 * s)
    ramp = dmin + span * (0.2 + 0.5 * (xx - x0) / (0.3 * s))
    depth = torch.where(m, ramp, depth)
    amp = torch.where(m, c.material() * (0.6 + 0.4 * torch.sign(torch.sin(xx * 0.9))), amp)
    return depth, amp


def _hemisphere(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """A hemisphere (smooth curved surface) with radial shading."""
    yy, xx, g, s, span, dmin = c.yy, c.xx, c.g, c.s, c.span, c.dmin
    h, w = yy.shape
    cy, cx, r = _u(g, 0.25, 0.75) * h, _u(g, 0.25, 0.75) * w, _u(g, 0.1, 0.16) * s
    rr2 = (yy - cy) ** 2 + (xx - cx) ** 2
    m = rr2 < r * r
    zc = _u(g, dmin + 0.3 * span, dmin + 0.6 * span)
    cap = zc - 0.12 * span * torch.sqrt(torch.clamp(1 - rr2 / (r * r), min=0.0))
    depth = torch.where(m, cap, depth)
    amp = torch.where(
        m, c.material() * (0.5 + 0.5 * torch.sqrt(torch.clamp(1 - rr2 / (r * r), min=0))), amp
    )
    return depth, amp


def _rings(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """Concentric rings: depth steps (contours) in a disc."""
    yy, xx, g, s, span, dmin, amax = c.yy, c.xx, c.g, c.s, c.span, c.dmin, c.amax
    h, w = yy.shape
    cy, cx, r = _u(g, 0.2, 0.8) * h, _u(g, 0.2, 0.8) * w, _u(g, 0.12, 0.18) * s
    rad = torch.sqrt((yy - cy) ** 2 + (xx - cx) ** 2)
    m = rad < r
    ring = torch.floor(rad / max(r / 5.0, 2.0))
    depth = torch.where(m, dmin + span * (0.15 + 0.08 * torch.remainder(ring, 3)), depth)
    amp = torch.where(m, amax * (0.2 + 0.25 * torch.remainder(ring, 2)), amp)
    return depth, amp


def _star(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """Siemens star: fine radial detail down to the pixel scale."""
    yy, xx, g, s, span, dmin = c.yy, c.xx, c.g, c.s, c.span, c.dmin
    h, w = yy.shape
    cy, cx, r = _u(g, 0.2, 0.8) * h, _u(g, 0.2, 0.8) * w, _u(g, 0.12, 0.17) * s
    rad = torch.sqrt((yy - cy) ** 2 + (xx - cx) ** 2)
    ang = torch.atan2(yy - cy, xx - cx)
    m = rad < r
    spoke = torch.sin(12 * ang) > 0
    zs = _u(g, dmin + 0.25 * span, dmin + 0.5 * span)
    depth = torch.where(m & spoke, torch.full_like(depth, zs), depth)
    depth = torch.where(m & ~spoke, torch.full_like(depth, zs + 0.15 * span), depth)
    amp = torch.where(m, torch.where(spoke, torch.full_like(amp, c.material()), amp), amp)
    return depth, amp


def _bars(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """Thin bars 1-3 px wide at several depths (fine details)."""
    yy, xx, g, span, dmin = c.yy, c.xx, c.g, c.span, c.dmin
    h, w = yy.shape
    for k in range(4):
        width = 1 + k % 3
        x0 = int(_u(g, 0.05, 0.9) * w)
        y0, y1 = int(_u(g, 0, 0.4) * h), int(_u(g, 0.6, 1.0) * h)
        m = (xx >= x0) & (xx < x0 + width) & (yy >= y0) & (yy < y1)
        depth = torch.where(m, torch.full_like(depth, _u(g, dmin, dmin + 0.4 * span)), depth)
        amp = torch.where(m, torch.full_like(amp, c.material()), amp)
    return depth, amp


def _grating(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """A depth grating (sinusoidal surface) patch."""
    yy, xx, g, s, span, dmin = c.yy, c.xx, c.g, c.s, c.span, c.dmin
    h, w = yy.shape
    y0, x0 = int(_u(g, 0, 0.7 * h)), int(_u(g, 0, 0.7 * w))
    m = (yy >= y0) & (yy < y0 + 0.25 * s) & (xx >= x0) & (xx < x0 + 0.25 * s)
    zg = _u(g, dmin + 0.3 * span, dmin + 0.7 * span)
    depth = torch.where(m, zg + 0.05 * span * torch.sin(2 * math.pi * (xx - x0) / 7.0), depth)
    amp = torch.where(m, torch.full_like(amp, c.material()), amp)
    return depth, amp


def _dark_object(c: _Canvas, depth: torch.Tensor, amp: torch.Tensor):
    """A dark, near-zero-amplitude object: the low end of the range."""
    yy, xx, g, s, span, dmin, dmax, amax = c.yy, c.xx, c.g, c.s, c.span, c.dmin, c.dmax, c.amax
    h, w = yy.shape
    cy, cx = _u(g, 0.1, 0.9) * h, _u(g, 0.1, 0.9) * w
    m = ((yy - cy) / (0.08 * s)) ** 2 + ((xx - cx) / (0.14 * s)) ** 2 < 1
    depth = torch.where(
        m, torch.full_like(depth, _u(g, dmin + 0.2 * span, dmax - 0.1 * span)), depth
    )
    amp = torch.where(m, torch.full_like(amp, amax * _u(g, 0.0, 0.04)), amp)
    return depth, amp
