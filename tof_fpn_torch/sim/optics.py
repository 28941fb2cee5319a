"""Optical and pixel effects of the diagnosis catalogue as simulator terms (see
:mod:`tof_fpn_torch.sim.effects` for the catalogue table and the chain order).

:class:`Vignetting` (lens fall-off), :class:`PixelGain` (PRNU), :class:`LensBlur` (the point-spread
function that makes flying pixels at depth edges) and :class:`Saturation` (full-well clip);
:class:`~tof_fpn_torch.sim.multipath.Multipath` (interreflection in the scene) has a module of its
own. All act on the correlation samples in e-.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from .camera import _as_float, _check_range
from .terms import SimState, Term, _num

__all__ = [
    "EDGE_STEP_M",
    "EdgeMixing",
    "LensBlur",
    "PixelGain",
    "Saturation",
    "Vignetting",
    "edge_partners",
]

#: a pixel is on a depth edge when a 4-neighbour's scene depth differs by more than this (m)
EDGE_STEP_M: float = 0.1


def _check_map(m, name: str, positive: bool) -> None:
    """A map field: None or a finite (H, W) tensor, > 0 (``positive``) or >= 0."""
    if m is None:
        return
    if not isinstance(m, torch.Tensor) or m.dim() != 2:
        got = tuple(m.shape) if isinstance(m, torch.Tensor) else type(m).__name__
        raise ValueError(f"{name} must be an (H, W) tensor, got {got}")
    if not bool(torch.isfinite(m).all()) or bool((m <= 0).any() if positive else (m < 0).any()):
        raise ValueError(f"{name} must be finite and {'> 0' if positive else '>= 0'}")


def _frame_map(m: torch.Tensor, name: str, h: int, w: int, like: torch.Tensor) -> torch.Tensor:
    """The (H, W) map field ``m`` as a (1, 1, H, W) tensor like ``like``; a map of another size
    than the frames is refused."""
    if tuple(m.shape) != (h, w):
        raise ValueError(f"{name} is {tuple(m.shape)}, the frames are {(h, w)}")
    return m.to(device=like.device, dtype=like.dtype).view(1, 1, h, w)


def _radius2(h: int, w: int, cx, cy, like: torch.Tensor) -> torch.Tensor:
    yy = torch.arange(h, device=like.device, dtype=like.dtype).view(h, 1) - (h - 1) / 2.0
    xx = torch.arange(w, device=like.device, dtype=like.dtype).view(1, w) - (w - 1) / 2.0
    half_diag2 = ((h - 1) / 2.0) ** 2 + ((w - 1) / 2.0) ** 2
    return ((xx - _num(cx, like)) ** 2 + (yy - _num(cy, like)) ** 2) / half_diag2


@dataclass
class Vignetting(Term):
    """Lens fall-off of the collected light: gain ``1 + a2 r^2 + a4 r^4`` on every sample, ``r``
    the distance from the optical centre (``centre_x``, ``centre_y`` px from the frame centre) in
    half-diagonals; or, with ``gain_map`` (H, W, > 0), that relative illumination itself (a
    fall-off of any shape: an elliptical lens, a mechanical vignette)."""

    quadratic: float = 0.0
    quartic: float = 0.0
    centre_x: float = 0.0
    centre_y: float = 0.0
    gain_map: object = None
    name: str = field(default="vignetting", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Vignetting:
        a2 = _as_float(self.quadratic, "Vignetting.quadratic")
        a4 = _as_float(self.quartic, "Vignetting.quartic")
        _as_float(self.centre_x, "Vignetting.centre_x")
        _as_float(self.centre_y, "Vignetting.centre_y")
        if 1 + min(0.0, a2) + min(0.0, a4) <= 0:
            raise ValueError(f"Vignetting gain must stay > 0 at r = 1, got a2={a2}, a4={a4}")
        _check_map(self.gain_map, "Vignetting.gain_map", positive=True)
        return self

    def gain(self, h: int, w: int, like: torch.Tensor) -> torch.Tensor:
        if self.gain_map is not None:
            return _frame_map(self.gain_map, "Vignetting.gain_map", h, w, like)
        r2 = _radius2(h, w, self.centre_x, self.centre_y, like)
        g = 1.0 + _num(self.quadratic, like) * r2 + _num(self.quartic, like) * r2 * r2
        return g.clamp_min(1e-3).view(1, 1, h, w)

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        state.samples = s * self.gain(s.shape[2], s.shape[3], s)
        return state


@dataclass
class PixelGain(Term):
    """Photo-response non-uniformity: pixel ``p`` collects ``g_p`` times the light, ``g_p = 1 +
    rms xi_p`` (fixed from ``seed``) or the given ``gain_map`` (H, W)."""

    rms: float = 0.0
    seed: int = 5
    gain_map: object = None
    name: str = field(default="pixel_gain", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> PixelGain:
        _check_range(self.rms, "PixelGain.rms", 0.0, strict=False)
        return self

    def gain(self, h: int, w: int, like: torch.Tensor) -> torch.Tensor:
        if self.gain_map is not None:
            g = torch.as_tensor(self.gain_map).to(device=like.device, dtype=like.dtype)
            if g.numel() != h * w:
                raise ValueError(f"PixelGain.gain_map must be ({h}, {w}), got {list(g.shape)}")
            return g.reshape(1, 1, h, w)
        gen = torch.Generator().manual_seed(int(self.seed))
        xi = torch.randn((h, w), generator=gen, dtype=torch.float64).to(like.device, like.dtype)
        return (1.0 + _num(self.rms, like) * xi).clamp_min(0.0).view(1, 1, h, w)

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        state.samples = s * self.gain(s.shape[2], s.shape[3], s)
        return state


@dataclass
class LensBlur(Term):
    """Gaussian point-spread function of ``sigma`` px on the correlation samples: a pixel next to
    a depth edge sums the returns of both surfaces, whose phasors mix into a depth between them
    (flying pixels). ``sigma = 0`` leaves the samples as they are."""

    sigma: float = 0.0
    name: str = field(default="flying_pixels", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> LensBlur:
        s = _check_range(self.sigma, "LensBlur.sigma", 0.0, strict=False, unit=" px")
        if s > 10:
            raise ValueError(f"LensBlur.sigma must be <= 10 px, got {s}")
        return self

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        sig = _num(self.sigma, s)
        if _as_float(self.sigma, "sigma") <= 0:
            return state
        r = max(1, math.ceil(3.0 * _as_float(self.sigma, "sigma")))
        x = torch.arange(-r, r + 1, device=s.device, dtype=s.dtype)
        k = torch.exp(-0.5 * (x / sig) ** 2)
        k = k / k.sum()
        b, n, h, w = s.shape
        y = F.pad(s.reshape(b * n, 1, h, w), (r, r, r, r), mode="replicate")
        y = F.conv2d(y, k.view(1, 1, 1, -1))
        y = F.conv2d(y, k.view(1, 1, -1, 1))
        state.samples = y.reshape(b, n, h, w)
        return state


def edge_partners(depth: torch.Tensor, step: float = EDGE_STEP_M) -> torch.Tensor:
    """For every pixel of ``depth`` (H, W) the flat index of its 4-neighbour across the largest
    depth step, or -1 where no 4-neighbour differs by more than ``step`` m (not on an edge, or
    an invalid depth)."""
    h, w = depth.shape
    idx = torch.arange(h * w, device=depth.device).view(h, w)
    d = torch.nan_to_num(depth, nan=0.0)
    best = torch.zeros_like(d)
    out = torch.full((h, w), -1, dtype=torch.long, device=depth.device)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nd = torch.roll(d, (dy, dx), (0, 1))
        ni = torch.roll(idx, (dy, dx), (0, 1))
        inside = torch.ones_like(d, dtype=torch.bool)
        if dy:
            inside[0 if dy > 0 else -1, :] = False
        if dx:
            inside[:, 0 if dx > 0 else -1] = False
        gap = (nd - d).abs()
        take = inside & (gap > step) & (gap > best) & (d > 0) & (nd > 0)
        best = torch.where(take, gap, best)
        out = torch.where(take, ni, out)
    return out


@dataclass
class EdgeMixing(Term):
    """Mixed pixels at depth edges with a random share: each pixel on a depth edge of the scene
    (:func:`edge_partners`) is, with probability ``probability``, a mixture ``(1 - s) x_p + s
    x_q`` of its own samples and those of its neighbour across the edge, ``s`` uniform in
    (0, 1) per pixel (its footprint covers a random part of the other surface); fixed over the
    frames (from ``seed``). Unlike :class:`LensBlur` the share is not set by a point-spread
    function.

    Args:
        probability: share of the edge pixels that are mixed, in [0, 1].
        seed: seed of which pixels mix and their shares.
    """

    probability: float = 0.0
    seed: int = 23
    name: str = field(default="edge_mixing", init=False)

    def __post_init__(self) -> None:
        _check_range(self.probability, "EdgeMixing.probability", 0.0, strict=False)
        if _as_float(self.probability, "probability") > 1:
            raise ValueError(f"EdgeMixing.probability must be <= 1, got {self.probability}")

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        b, n, h, w = s.shape
        part = edge_partners(state.scene.depth[0, 0].to(torch.float64))
        gen = torch.Generator().manual_seed(int(self.seed))
        u = torch.rand((2, h, w), generator=gen, dtype=torch.float64).to(s.device)
        mix = (part >= 0) & (u[0] < _as_float(self.probability, "probability"))
        share = torch.where(mix, u[1], torch.zeros_like(u[1])).to(s.dtype)
        flat = s.reshape(b, n, h * w)
        other = flat[:, :, part.clamp_min(0).view(-1)].view(b, n, h, w)
        state.samples = s + share.view(1, 1, h, w) * (other - s)
        return state


def soft_limit(samples: torch.Tensor, level, knee) -> tuple[torch.Tensor, torch.Tensor]:
    """Samples ``R`` (e-) compressed softly towards ``level`` over a ``knee`` (> 0), and the
    slope of the compression at each: ``f(R) = (g(R) - g(0)) / g'(0)`` with ``g(R) = level - knee
    softplus((level - R) / knee)``, ``g'(R) = sigmoid((level - R) / knee)``. The normalisation
    keeps a dark sample as it is (``f(0) = 0``, slope 1 at 0): without it every sample, however
    far below the level, would be scaled by ``g'(0) < 1`` (0.98 for a knee a quarter of the
    level), and a level far above the data would still bend all of it."""
    level = torch.as_tensor(level, dtype=samples.dtype, device=samples.device)
    knee = torch.as_tensor(knee, dtype=samples.dtype, device=samples.device)
    s0 = torch.sigmoid(level / knee)
    # g(R) - g(0) in the form that has no difference of two large numbers: below the level
    # R - knee [softplus((R - level) / knee) - softplus(-level / knee)], above it
    # knee [softplus(level / knee) - softplus((level - R) / knee)]
    below = samples - knee * (F.softplus((samples - level) / knee) - F.softplus(-level / knee))
    above = knee * (F.softplus(level / knee) - F.softplus((level - samples) / knee))
    out = torch.where(samples <= level, below, above) / s0
    return out, torch.sigmoid((level - samples) / knee) / s0


@dataclass
class Saturation(Term):
    """Full-well / anti-blooming limit: every sample is clipped at ``level`` e-, softly over a
    ``knee`` (e-; 0: a hard clip) by :func:`soft_limit`."""

    level: float = 1e9
    knee: float = 0.0
    name: str = field(default="saturation", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Saturation:
        _check_range(self.level, "Saturation.level", 0.0, strict=True, unit=" e-")
        _check_range(self.knee, "Saturation.knee", 0.0, strict=False, unit=" e-")
        return self

    def noisy_moments(
        self, mean: torch.Tensor, var: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and variance of a hard clip ``min(R, level)`` of Gaussian samples ``R`` with
        ``mean`` and ``var`` (e-, e-^2): what a camera that clips its *noisy* samples records on
        average. With ``z = (level - mean) / sd``, ``Phi`` / ``phi`` the normal cdf / pdf and
        ``Q = 1 - Phi``: ``E = level - sd (z Phi + phi)``, ``Var = sd^2 (Phi - z phi + z^2 Q -
        (z Q - phi)^2)`` (the clipped part is a point mass at the level). The clip bends the mean
        over about one noise sd and removes the noise of the clipped part: a fully clipped sample
        reads the level with no variance."""
        dt = mean.dtype
        mu, v = mean.double(), var.double().clamp_min(1e-12)
        sd = torch.sqrt(v)
        lv = _num(self.level, mu)
        z = (lv - mu) / sd
        cdf, q = torch.special.ndtr(z), torch.special.ndtr(-z)
        pdf = torch.exp(-0.5 * z * z) / math.sqrt(2 * math.pi)
        m1 = z * q - pdf
        var_u = (cdf - z * pdf + z * z * q - m1 * m1).clamp_min(0.0)
        return (lv - sd * (z * cdf + pdf)).to(dt), (v * var_u).to(dt)

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        lv = _num(self.level, s)
        if _as_float(self.knee, "knee") > 0:
            state.samples = soft_limit(s, lv, _num(self.knee, s))[0]
        else:
            state.samples = torch.minimum(
                s, lv if isinstance(lv, torch.Tensor) else s.new_tensor(lv)
            )
        sat = (s >= lv).any(dim=1, keepdim=True)
        if state.saturated is None or state.saturated.shape != sat.shape:
            state.saturated = sat if state.saturated is None else state.saturated | sat
        else:
            state.saturated = state.saturated | sat
        return state
