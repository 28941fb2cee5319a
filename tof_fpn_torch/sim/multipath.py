"""Multipath interference in the simulator: :class:`Multipath` (a uniform second return, the
relay within the visible scene and specular paths off its planes; the geometry in
:mod:`tof_fpn_torch.sim.relay`) and :func:`source_step`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .. import constants as K
from .camera import _check_range
from .optics import _check_map, _frame_map
from .phasor import _phase_per_metre, rotate_fundamental
from .relay import mirror_gains, scene_relay
from .terms import SimState, Term, _num

__all__ = ["Multipath", "source_step"]


def source_step(h: int, w: int, relay_step: int = K.MULTIPATH_RELAY_STEP) -> int:
    """Pixels between the relay's source patches in (H, W) frames: at least ``relay_step`` and
    at most ``MULTIPATH_MAX_SOURCES`` sources (the relay is a (sources x pixels) matrix: memory
    and time grow with both)."""
    return max(int(relay_step), math.ceil(math.sqrt(h * w / K.MULTIPATH_MAX_SOURCES)))


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
            samples = samples * _frame_map(self.source_map, "Multipath.source_map", h, w, samples)
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
