"""Physical terms of the raw-level ToF simulator.

A simulation is a list of terms applied in order to a :class:`SimState` whose ``samples`` hold the
N correlation samples ``R_n`` (B, N, H, W): first in electrons (e-), after :class:`ADC` in DN. Each
term is a dataclass with a ``name`` and plain numeric fields (Python numbers, or 0-d tensors with
``requires_grad`` when fitting; the quantiser and the random masks are not differentiable).

Default chain (:func:`default_terms`)::

    Photons -> ShotNoise -> ReadoutFPN -> ReadNoise -> ADC -> ImpulsivePixels

Signal model (``Photons``): the scene irradiance from the illumination is
``E_act = P / (Omega d^2)`` (power ``P`` spread over a solid angle ``Omega``, inverse-square
fall-off) and the ambient one ``E_amb``; the pixel collects ``k rho E`` e-/s (``k``: responsivity,
``rho``: reflectance). Per sample of integration time ``T``::

    R_n = T [ k rho E_act (1 + m cos(phi + 2 pi n / N)) + k rho E_amb ]       (e-)

so the amplitude is ``T k rho E_act m`` and the offset ``T k rho (E_act + E_amb)`` (``m``:
demodulation contrast), ``phi = 4 pi f d / c_L``.

Read-out terms (FPN, ADC, impulsive pixels): :mod:`tof_fpn_torch.sim.readout`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import torch

from .camera import SPEED_OF_LIGHT_AIR, Camera, _check_range
from .scenes import Scene

__all__ = ["Joined", "Photons", "ReadNoise", "ShotNoise", "SimState", "Term"]


@dataclass
class SimState:
    """What flows through the terms.

    Attributes:
        camera, scene: the inputs (``scene`` holds the B_s scenes, not repeated per frame).
        samples: (B, N, H, W) correlation samples, e- until :class:`ADC`, DN after. Noise-free
            terms may leave one entry per scene; the first temporal-noise term expands it to
            ``B = scenes x frames`` (frame ``f`` of scene ``b`` at ``b * frames + f``).
        frames: captures per scene.
        unit: ``"e-"`` or ``"DN"``.
        generator: random source for temporal noise (on the samples' device).
        saturated: (B, 1, H, W) bool, pixels where a sample hit full well or the top ADC code.
        impulsive: (B, 1, H, W) bool, pixels replaced by :class:`ImpulsivePixels`.
    """

    camera: Camera
    scene: Scene
    samples: torch.Tensor
    generator: torch.Generator
    frames: int = 1
    unit: str = "e-"
    saturated: torch.Tensor | None = None
    impulsive: torch.Tensor | None = None

    @property
    def expanded(self) -> bool:
        """Whether ``samples`` already has one entry per frame (B = scenes x frames)."""
        return self.frames == 1 or self.samples.shape[0] == self.scene.depth.shape[0] * self.frames

    def expand(self) -> SimState:
        """Repeat the per-scene samples (and masks) to one entry per frame, if not yet done."""
        if not self.expanded:
            f = self.frames
            self.samples = self.samples.repeat_interleave(f, dim=0)
            if self.saturated is not None:
                self.saturated = self.saturated.repeat_interleave(f, dim=0)
            if self.impulsive is not None:
                self.impulsive = self.impulsive.repeat_interleave(f, dim=0)
        return self


class Term:
    """Base of all terms: ``name`` plus ``apply(state) -> state``; fields are the parameters."""

    name: str = "term"

    def apply(self, state: SimState) -> SimState:  # pragma: no cover - interface
        raise NotImplementedError

    def validate(self) -> Term:
        return self

    def parameters(self) -> dict:
        """Numeric fields as ``{field: value}`` (what a fit may change)."""
        out = {}
        for f in fields(self):  # type: ignore[arg-type]
            v = getattr(self, f.name)
            if isinstance(v, (int, float, torch.Tensor)) and not isinstance(v, bool):
                out[f.name] = v
            elif isinstance(v, tuple) and all(
                isinstance(t, (int, float, torch.Tensor)) and not isinstance(t, bool) for t in v
            ):
                out[f.name] = v
        return out


@dataclass
class Joined(Term):
    """Terms applied in turn under one name: two forms of one effect at one stage of the chain
    (e.g. the catalogue's cyclic error and a delay periodic in the phase). ``parts``: the terms;
    ``name``: the stage's name (a :class:`Simulation` holds each name once)."""

    parts: tuple = ()
    name: str = "joined"

    def validate(self) -> Joined:
        for t in self.parts:
            if not isinstance(t, Term):
                raise ValueError(f"Joined.parts must be Term instances, got {type(t).__name__}")
            t.validate()
        return self

    def apply(self, state: SimState) -> SimState:
        for t in self.parts:
            state = t.apply(state)
        return state


def _owned(x: torch.Tensor) -> bool:
    """Whether a term may update ``x`` in place (an internal tensor outside any autograd graph)."""
    return not (torch.is_grad_enabled() and x.requires_grad)


def _randn(shape, generator: torch.Generator, like: torch.Tensor) -> torch.Tensor:
    """Standard normals on ``like``'s device and dtype (``normal_`` is the fastest CPU path)."""
    return torch.empty(shape, device=like.device, dtype=like.dtype).normal_(generator=generator)


def _num(x, like: torch.Tensor):
    """A field value usable in torch arithmetic with ``like`` (keeps tensors, graph included)."""
    if isinstance(x, torch.Tensor):
        return x.to(device=like.device, dtype=like.dtype)
    return float(x)


@dataclass
class Photons(Term):
    """Mean photo-charge of every correlation sample (active illumination + ambient light).

    Args:
        responsivity: ``k``, e-/s per W/m^2 of scene irradiance at reflectance 1 (> 0); lumps
            lens, pixel area, fill factor and quantum efficiency.
        solid_angle: ``Omega``, sr (> 0), over which the illumination power spreads.
        modulation_contrast: ``m`` in (0, 1], demodulation contrast.
    """

    responsivity: float = 2.0e8
    solid_angle: float = 0.5
    modulation_contrast: float = 0.5
    name: str = field(default="photons", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Photons:
        _check_range(self.responsivity, "Photons.responsivity", 0.0, strict=True)
        _check_range(self.solid_angle, "Photons.solid_angle", 0.0, strict=True, unit=" sr")
        m = _check_range(self.modulation_contrast, "Photons.modulation_contrast", 0.0, strict=True)
        if m > 1:
            raise ValueError(f"Photons.modulation_contrast must be in (0, 1], got {m!r}")
        return self

    def mean_samples(self, camera: Camera, scene: Scene) -> torch.Tensor:
        """Noise-free ``R_n`` in e-, (B, N, H, W), for the scene's batch."""
        d, rho = scene.depth, scene.reflectance
        n = camera.n_phases
        T = _num(camera.integration_time, d)
        k = _num(self.responsivity, d)
        e_act = _num(camera.illumination_power, d) / (_num(self.solid_angle, d) * d * d)
        active = (T * k) * rho * e_act  # (B,1,H,W) e-
        ambient = (T * k * _num(camera.ambient_irradiance, d)) * rho
        phi = d * (4.0 * math.pi * _num(camera.modulation_frequency, d) / SPEED_OF_LIGHT_AIR)
        theta = torch.arange(n, device=d.device, dtype=torch.float64) * (2 * math.pi / n)
        cos_t = torch.cos(theta).to(d.dtype).view(1, n, 1, 1)
        sin_t = torch.sin(theta).to(d.dtype).view(1, n, 1, 1)
        # cos(phi + t) = cos(phi) cos(t) - sin(phi) sin(t): two maps instead of N cosines
        amp = active * _num(self.modulation_contrast, d)
        return (active + ambient) + amp * (torch.cos(phi) * cos_t - torch.sin(phi) * sin_t)

    def apply(self, state: SimState) -> SimState:
        state.samples = self.mean_samples(state.camera, state.scene)
        state.unit = "e-"
        return state


@dataclass
class ShotNoise(Term):
    """Photon shot noise: ``R_n ~ Poisson(R_n)``.

    Args:
        exact: ``False`` (default) draws the Gaussian approximation ``R + sqrt(R) xi``, accurate
            above ~10 e- and fast; ``True`` draws :func:`torch.poisson` (not differentiable).
    """

    exact: bool = False
    name: str = field(default="shot_noise", init=False)

    def apply(self, state: SimState) -> SimState:
        if self.exact:
            r = state.expand().samples.clamp(min=0.0)
            state.samples = torch.poisson(r, generator=state.generator)
            return state
        r = state.samples.clamp(min=0.0)
        if state.expanded:
            noise = _randn(r.shape, state.generator, r)
            state.samples = torch.addcmul(r, noise, torch.sqrt(r))
            return state
        # per-scene means: draw all frames at once and broadcast mean and sqrt(mean) over them
        b, n, h, w = r.shape
        f = state.frames
        noise = _randn((b, f, n, h, w), state.generator, r)
        if _owned(noise) and not r.requires_grad:
            noise.mul_(torch.sqrt(r).unsqueeze(1)).add_(r.unsqueeze(1))
            out = noise
        else:
            out = torch.addcmul(r.unsqueeze(1), noise, torch.sqrt(r).unsqueeze(1))
        state.samples = out.view(b * f, n, h, w)
        if state.saturated is not None:
            state.saturated = state.saturated.repeat_interleave(f, dim=0)
        if state.impulsive is not None:
            state.impulsive = state.impulsive.repeat_interleave(f, dim=0)
        return state


@dataclass
class ReadNoise(Term):
    """Gaussian read-out noise of ``camera.read_noise`` e- rms per sample (temporal)."""

    name: str = field(default="read_noise", init=False)

    def apply(self, state: SimState) -> SimState:
        s = state.expand().samples
        sigma = _num(state.camera.read_noise, s)
        noise = _randn(s.shape, state.generator, s)
        if isinstance(sigma, float) and _owned(s):
            state.samples = s.add_(noise, alpha=sigma)
        else:
            state.samples = s + sigma * noise
        return state
