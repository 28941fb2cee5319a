"""Optical and pixel effects of the diagnosis catalogue as simulator terms (see
:mod:`tof_fpn_torch.sim.effects` for the catalogue table and the chain order).

:class:`Vignetting` (lens fall-off), :class:`PixelGain` (PRNU), :class:`LensBlur` (the point-spread
function that makes flying pixels at depth edges), :class:`Saturation` (full-well clip) and
:class:`Multipath` (diffuse interreflection in the scene). All act on the correlation samples in e-.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

from .. import constants as K
from .camera import _as_float, _check_range
from .phasor import _phase_per_metre, rotate_fundamental
from .relay import mirror_gains, scene_relay
from .terms import SimState, Term, _num

__all__ = [
    "EDGE_STEP_M",
    "EdgeMixing",
    "LensBlur",
    "Multipath",
    "PixelGain",
    "Saturation",
    "Vignetting",
    "edge_partners",
    "source_step",
]

#: a pixel is on a depth edge when a 4-neighbour's scene depth differs by more than this (m)
EDGE_STEP_M: float = 0.1


def source_step(h: int, w: int, relay_step: int = K.MULTIPATH_RELAY_STEP) -> int:
    """Pixels between the relay's source patches in (H, W) frames: at least ``relay_step`` and
    at most ``MULTIPATH_MAX_SOURCES`` sources (the relay is a (sources x pixels) matrix: memory
    and time grow with both)."""
    return max(int(relay_step), math.ceil(math.sqrt(h * w / K.MULTIPATH_MAX_SOURCES)))


def _check_map(m, name: str, positive: bool) -> None:
    """A map field: None or a finite (H, W) tensor, > 0 (``positive``) or >= 0."""
    if m is None:
        return
    if not isinstance(m, torch.Tensor) or m.dim() != 2:
        got = tuple(m.shape) if isinstance(m, torch.Tensor) else type(m).__name__
        raise ValueError(f"{name} must be an (H, W) tensor, got {got}")
    if not bool(torch.isfinite(m).all()) or bool((m <= 0).any() if positive else (m < 0).any()):
        raise ValueError(f"{name} must be finite and {'> 0' if positive else '>= 0'}")


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
            if tuple(self.gain_map.shape) != (h, w):
                raise ValueError(
                    f"Vignetting.gain_map is {tuple(self.gain_map.shape)}, the frames are {(h, w)}"
                )
            return self.gain_map.to(device=like.device, dtype=like.dtype).view(1, 1, h, w)
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


@dataclass
class Saturation(Term):
    """Full-well / anti-blooming limit: every sample is clipped at ``level`` e-, softly over a
    ``knee`` (e-; 0: a hard clip): ``level - knee softplus((level - R) / knee)``."""

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
            kn = _num(self.knee, s)
            state.samples = lv - kn * F.softplus((lv - s) / kn)
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


@dataclass
class Multipath(Term):
    """Diffuse multipath interference (after Fuchs 2010, "Multipath interference compensation in
    time-of-flight camera images", simplified to a uniform relay): the light every scene point
    reflects lights every other point a second time, over a longer path.

    The relayed irradiance is taken uniform over the scene (a diffuse room): its phasor is the
    scene-mean of the direct returns, delayed by ``extra_path`` (m, the mean extra distance the
    relayed light travels). Pixel ``p`` reflects it with its own albedo, so its complex
    correlation gets a second return

        ``X_p += strength * (rho_p / mean rho) * mean_q(X_q) * exp(j 4 pi f extra_path / c_L)``

    (``X``: the samples' first harmonic; the offset of the relayed light is added likewise).
    ``strength`` is the relayed light relative to the direct light of a pixel of mean
    reflectance (0: none). Dark and far pixels, whose direct return is weak, move most: towards
    the phase of the relayed light, i.e. mostly further away.

    ``scene_relay`` adds the relay *within the visible scene*, with its geometry
    (:mod:`tof_fpn_torch.sim.relay`): the scene is back-projected through a pinhole of horizontal
    field of view ``field_of_view`` (deg), every scene point relays the light it reflects to
    every other with a Lambertian inverse square (near-field length ``near_field``, m) over its
    own extra path; ``scene_relay`` is the relay efficiency (1: every pair of points facing each
    other; ``relay_step``: px between the source patches, raised so that at most
    ``MULTIPATH_MAX_SOURCES`` are used). The uniform part then stands for light relayed from
    outside the field of view.

    ``source_map`` (H, W), optional, >= 0: the share of its light each scene point relays, in
    place of the same efficiency everywhere (a free relay per surface: a glossy floor, one bright
    wall; multiplies ``scene_relay``). ``cosines``: the relay's form factor with both
    obliquities from the surface normals (:mod:`tof_fpn_torch.sim.relay`).

    ``mirrors`` (M, 5), optional: specular second paths, rows ``(nx, ny, nz, c, weight)``: the
    plane ``n . X = c`` (camera frame, m, ``c > 0``) mirrors the emitter and every point on the
    camera's side of it is lit once more from the image emitter, over the path ``d + L``, with
    ``weight (d / L)^2`` of its direct light (:func:`~tof_fpn_torch.sim.relay.mirror_gains`; a
    glossy floor or a window pane; ``weight``: the plane's specular reflectance, both ways).
    Added to the scene relay (multiplies ``scene_relay`` likewise).
    """

    strength: float = 0.0
    extra_path: float = 0.0
    scene_relay: float = 0.0
    field_of_view: float = K.MULTIPATH_FIELD_OF_VIEW_DEG
    near_field: float = K.MULTIPATH_NEAR_FIELD_M
    relay_step: int = K.MULTIPATH_RELAY_STEP
    source_map: torch.Tensor | None = None
    cosines: bool = False
    mirrors: torch.Tensor | None = None
    name: str = field(default="multipath", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Multipath:
        b = _check_range(self.strength, "Multipath.strength", 0.0, strict=False)
        if b > 1:
            raise ValueError(f"Multipath.strength must be <= 1, got {b}")
        _check_range(self.extra_path, "Multipath.extra_path", 0.0, strict=False, unit=" m")
        _check_range(self.scene_relay, "Multipath.scene_relay", 0.0, strict=False)
        fov = _check_range(self.field_of_view, "Multipath.field_of_view", 0.0, strict=True)
        if fov >= 180.0:
            raise ValueError(f"Multipath.field_of_view must be < 180 deg, got {fov}")
        _check_range(self.near_field, "Multipath.near_field", 0.0, strict=True, unit=" m")
        if int(self.relay_step) != self.relay_step or self.relay_step < 1:
            raise ValueError(f"Multipath.relay_step must be an integer >= 1, got {self.relay_step}")
        _check_map(self.source_map, "Multipath.source_map", positive=False)
        r = self.mirrors
        if r is not None:
            if not isinstance(r, torch.Tensor) or r.dim() != 2 or r.shape[1] != 5:
                raise ValueError(
                    "Multipath.mirrors must be an (M, 5) tensor of rows (nx, ny, nz, c, weight), "
                    f"got {tuple(r.shape) if isinstance(r, torch.Tensor) else type(r).__name__}"
                )
            if not bool(torch.isfinite(r).all()) or bool((r[:, 3:] < 0).any()):
                raise ValueError("Multipath.mirrors must be finite with offsets and weights >= 0")
        return self

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        rho = state.scene.reflectance.to(device=s.device, dtype=s.dtype)
        rel = rho / rho.mean(dim=(2, 3), keepdim=True).clamp_min(1e-12)
        mean = s.mean(dim=(2, 3), keepdim=True)
        psi = _num(self.extra_path, s) * _phase_per_metre(state.camera)
        relay = rotate_fundamental(
            mean, psi if isinstance(psi, torch.Tensor) else s.new_tensor(psi)
        )
        out = s + _num(self.strength, s) * rel * relay
        if not (isinstance(self.scene_relay, (int, float)) and self.scene_relay == 0):
            out = out + _num(self.scene_relay, s) * self.relayed(s, state)
        state.samples = out
        return state

    def relayed(self, samples: torch.Tensor, state: SimState) -> torch.Tensor:
        """The light relayed within the visible scene at unit ``scene_relay`` (samples' unit)."""
        sc = state.scene
        per = samples.shape[0] // sc.depth.shape[0]
        h, w = samples.shape[-2:]
        out = self._mirrored(samples, state)
        if self.source_map is not None:
            if tuple(self.source_map.shape) != (h, w):
                raise ValueError(
                    f"Multipath.source_map is {tuple(self.source_map.shape)}, the frames are "
                    f"{(h, w)}"
                )
            samples = samples * self.source_map.to(samples.device, samples.dtype)
        step = source_step(h, w, self.relay_step)
        parts = [
            scene_relay(
                samples[i * per : (i + 1) * per],
                sc.depth[i, 0],
                sc.reflectance[i, 0],
                float(self.field_of_view),
                float(self.near_field),
                step,
                _phase_per_metre(state.camera),
                bool(self.cosines),
            )
            for i in range(sc.depth.shape[0])
        ]
        return torch.cat(parts, 0) if out is None else torch.cat(parts, 0) + out

    def _mirrored(self, samples: torch.Tensor, state: SimState) -> torch.Tensor | None:
        """The light of the specular paths of ``mirrors`` (None without any)."""
        r = self.mirrors
        if r is None or r.shape[0] == 0 or not bool((r[:, 4] > 0).any()):
            return None
        sc = state.scene
        per = samples.shape[0] // sc.depth.shape[0]
        k = _phase_per_metre(state.camera)
        parts = []
        for i in range(sc.depth.shape[0]):
            gain, psi = mirror_gains(sc.depth[i, 0], float(self.field_of_view), r[:, :4], k)
            s = samples[i * per : (i + 1) * per]
            one = torch.zeros_like(s)
            for m in range(r.shape[0]):
                g = (gain[m] * r[m, 4]).to(s.device, s.dtype)
                one = one + g * rotate_fundamental(s, psi[m].to(s.device, s.dtype))
            parts.append(one)
        return torch.cat(parts, 0)
