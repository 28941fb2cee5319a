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

Fixed-pattern noise (``ReadoutFPN``): the column (or row) read-out chain adds an offset and a gain
error to every sample, ``R_n <- g_n(x) R_n + o_n(x)``. A pattern identical in all N samples only
shifts the offset ``B`` (bin 0 of the DFT) and leaves the depth untouched; what reaches the depth is
its first DFT harmonic over n. Physically this is the tap / read-out mismatch between the samples:
sample n is read with a weight ``w_n = cos(2 pi n / N - psi)`` of a column pattern ``p(x)``::

    o_n(x) = sum_k a_k cos(w_k x + theta_k) w_n + sigma_o xi_o[n, x]
    g_n(x) = 1 + sum_k c_k cos(w_k x + theta_k) w_n + sigma_g xi_g[n, x]

(``w_k`` the FPN frequencies, default ``2 pi / 3`` and ``pi``; ``xi`` fixed standard normals from
the term's own ``seed``). The offset part adds ``(N/2) e^{j psi} p(x)`` to ``X_1 = (N A/2) e^{j phi}``,
a depth error ``~ (c_L / 4 pi f) p(x) sin(psi - phi) / A``: it grows as the amplitude falls, as in
Sec. II-B; the gain part adds ``~ c(x) B / A``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import torch

from .camera import SPEED_OF_LIGHT_AIR, Camera, _as_float, _check_range
from .scenes import Scene

__all__ = [
    "ADC",
    "ImpulsivePixels",
    "Photons",
    "ReadNoise",
    "ReadoutFPN",
    "ShotNoise",
    "SimState",
    "Term",
    "default_terms",
]


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


_AXES = ("columns", "rows")


@dataclass
class ReadoutFPN(Term):
    """Column- (or row-) wise read-out offsets and gains: the physical origin of ToF FPN.

    ``R_n(y, x) <- g_n(x) R_n(y, x) + o_n(x)`` with ``x`` the column index (``axis="columns"``,
    vertical stripes) or the row index (``axis="rows"``); formulas in the module docstring.

    Args:
        frequencies: FPN frequencies ``w_k`` in rad/sample, each in (0, pi]; default
            ``(2 pi / 3, pi)`` (Sec. III-A).
        offset_amplitudes: ``a_k``, e-, one per frequency (>= 0).
        gain_amplitudes: ``c_k``, relative, one per frequency (>= 0).
        spatial_phases: ``theta_k``, rad, one per frequency.
        sample_phase: ``psi``, rad: how the pattern is split over the N samples.
        random_offset: ``sigma_o``, e- rms of the non-periodic per-column offsets (>= 0).
        random_gain: ``sigma_g``, relative rms of the non-periodic per-column gains (>= 0).
        axis: ``"columns"`` or ``"rows"``.
        seed: seed of the fixed random part (the same pattern in every frame).
    """

    frequencies: tuple[float, ...] = (2 * math.pi / 3, math.pi)
    offset_amplitudes: tuple[float, ...] = (40.0, 40.0)
    gain_amplitudes: tuple[float, ...] = (0.002, 0.002)
    spatial_phases: tuple[float, ...] = (0.0, 0.0)
    sample_phase: float = 0.25 * math.pi
    random_offset: float = 10.0
    random_gain: float = 0.0005
    axis: str = "columns"
    seed: int = 20150413
    name: str = field(default="readout_fpn", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> ReadoutFPN:
        k = len(self.frequencies)
        for w in self.frequencies:
            wv = _as_float(w, "ReadoutFPN.frequencies")
            if not (0 < wv <= math.pi + 1e-12):
                raise ValueError(
                    f"ReadoutFPN.frequencies must lie in (0, pi], got {self.frequencies!r}"
                )
        for nm in ("offset_amplitudes", "gain_amplitudes", "spatial_phases"):
            v = getattr(self, nm)
            if len(v) != k:
                raise ValueError(
                    f"ReadoutFPN.{nm} must have one entry per frequency ({k}), got {len(v)}: {v!r}"
                )
        for a in self.offset_amplitudes:
            _check_range(a, "ReadoutFPN.offset_amplitudes", 0.0, strict=False, unit=" e-")
        for c in self.gain_amplitudes:
            _check_range(c, "ReadoutFPN.gain_amplitudes", 0.0, strict=False)
        _check_range(self.random_offset, "ReadoutFPN.random_offset", 0.0, strict=False, unit=" e-")
        _check_range(self.random_gain, "ReadoutFPN.random_gain", 0.0, strict=False)
        _as_float(self.sample_phase, "ReadoutFPN.sample_phase")
        if self.axis not in _AXES:
            raise ValueError(f"ReadoutFPN.axis must be one of {_AXES}, got {self.axis!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"ReadoutFPN.seed must be an int >= 0, got {self.seed!r}")
        return self

    def patterns(
        self, n: int, length: int, device: torch.device, dtype: torch.dtype
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Offsets ``o_n(x)`` (e-) and gains ``g_n(x)``, each (N, length): fixed across frames."""
        gen = torch.Generator().manual_seed(self.seed)
        xi_o = torch.randn((n, length), generator=gen, dtype=torch.float64)
        xi_g = torch.randn((n, length), generator=gen, dtype=torch.float64)
        xi_o, xi_g = xi_o.to(device=device, dtype=dtype), xi_g.to(device=device, dtype=dtype)
        x = torch.arange(length, device=device, dtype=torch.float64)
        nn_ = torch.arange(n, device=device, dtype=torch.float64)
        psi = self.sample_phase
        psi = (
            psi.to(device=device, dtype=torch.float64)
            if isinstance(psi, torch.Tensor)
            else float(psi)
        )
        w_n = torch.cos(nn_ * (2 * math.pi / n) - psi).to(dtype).view(n, 1)
        off = torch.zeros((1, length), device=device, dtype=dtype)
        gain = torch.zeros((1, length), device=device, dtype=dtype)
        for w, a, c, th in zip(
            self.frequencies,
            self.offset_amplitudes,
            self.gain_amplitudes,
            self.spatial_phases,
            strict=True,
        ):
            p = torch.cos(x * float(w) + float(th)).to(dtype).view(1, length)
            off = off + _num(a, p) * p
            gain = gain + _num(c, p) * p
        offsets = off * w_n + _num(self.random_offset, xi_o) * xi_o
        gains = 1.0 + gain * w_n + _num(self.random_gain, xi_g) * xi_g
        return offsets, gains

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        _, n, h, w = s.shape
        length = w if self.axis == "columns" else h
        off, gain = self.patterns(n, length, s.device, s.dtype)
        if self.axis == "columns":
            off, gain = off.view(1, n, 1, w), gain.view(1, n, 1, w)
        else:
            off, gain = off.view(1, n, h, 1), gain.view(1, n, h, 1)
        if _owned(s) and not (gain.requires_grad or off.requires_grad) and state.expanded:
            state.samples = s.mul_(gain).add_(off)
        else:
            state.samples = torch.addcmul(off, s, gain)
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


@dataclass
class ADC(Term):
    """Full-well clipping, conversion to DN and quantisation to ``camera.adc_bits``.

    ``DN = clamp(round(clamp(R, max=full_well) / conversion_gain), 0, 2**bits - 1)``; pixels with
    any sample at full well or at the top code are flagged in ``state.saturated``.

    Args:
        quantize: round to integer codes (default True; False keeps a differentiable chain).
    """

    quantize: bool = True
    name: str = field(default="adc", init=False)

    def apply(self, state: SimState) -> SimState:
        cam = state.camera
        s = state.samples
        full = _num(cam.full_well, s)
        top = float(cam.max_code)
        gain = _num(cam.conversion_gain, s)
        if _owned(s) and isinstance(full, float) and isinstance(gain, float):
            # round(min(R, full) / g) == min(round(R / g), round(full / g)): one clamp, in place
            cap = min(top, float(round(full / gain))) if self.quantize else min(top, full / gain)
            dn = s.mul_(1.0 / gain)
            if self.quantize:
                dn = dn.round_()
            dn = dn.clamp_(0.0, cap)
            sat = (dn >= cap).any(dim=1, keepdim=True)
        else:
            sat = (s >= full).any(dim=1, keepdim=True)
            dn = torch.clamp(s, max=full) / gain
            if self.quantize:
                dn = torch.round(dn)
            dn = torch.clamp(dn, 0.0, top)
            sat = sat | (dn >= top).any(dim=1, keepdim=True)
        state.saturated = sat if state.saturated is None else state.saturated | sat
        state.samples = dn
        state.unit = "DN"
        return state


_IMP_MODES = ("uniform", "dead")


@dataclass
class ImpulsivePixels(Term):
    """Impulsive / no-information pixels (the paper's IMP, Table II).

    A share ``rate`` of pixels loses its signal: ``"uniform"`` replaces its N samples by
    independent uniform codes in ``[0, level * (2**bits - 1)]`` (random phase: a depth spike);
    ``"dead"`` sets them to 0 (amplitude 0, depth 0: the usual invalid code).

    Args:
        rate: probability per pixel, in [0, 1].
        mode: ``"uniform"`` or ``"dead"``.
        level: top of the uniform codes as a fraction of full scale, in (0, 1].
        persistent: ``True`` -- the same pixels in every frame (defects, from ``seed``);
            ``False`` -- drawn anew every frame from the simulation's generator.
        seed: seed of the persistent mask.
    """

    rate: float = 0.0
    mode: str = "uniform"
    level: float = 0.05
    persistent: bool = False
    seed: int = 7
    name: str = field(default="impulsive", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> ImpulsivePixels:
        r = _check_range(self.rate, "ImpulsivePixels.rate", 0.0, strict=False)
        if r > 1:
            raise ValueError(f"ImpulsivePixels.rate must be in [0, 1], got {r!r}")
        if self.mode not in _IMP_MODES:
            raise ValueError(f"ImpulsivePixels.mode must be one of {_IMP_MODES}, got {self.mode!r}")
        lv = _check_range(self.level, "ImpulsivePixels.level", 0.0, strict=True)
        if lv > 1:
            raise ValueError(f"ImpulsivePixels.level must be in (0, 1], got {lv!r}")
        return self

    def apply(self, state: SimState) -> SimState:
        rate = _as_float(self.rate, "rate")
        s = (state.expand() if rate > 0 else state).samples
        b, n, h, w = s.shape
        if rate <= 0.0:
            mask = torch.zeros((b, 1, h, w), dtype=torch.bool, device=s.device)
        elif self.persistent:
            g = torch.Generator().manual_seed(self.seed)
            mask = (torch.rand((1, 1, h, w), generator=g) < rate).to(s.device).expand(b, 1, h, w)
        else:
            u = torch.rand((b, 1, h, w), generator=state.generator, device=s.device)
            mask = u < rate
        if rate > 0.0:
            if self.mode == "dead":
                repl = torch.zeros_like(s)
            else:
                top = (
                    state.camera.max_code
                    if state.unit == "DN"
                    else _as_float(state.camera.full_well, "full_well")
                )
                repl = torch.rand(
                    s.shape, generator=state.generator, device=s.device, dtype=s.dtype
                )
                repl = repl * (_as_float(self.level, "level") * top)
                if state.unit == "DN":
                    repl = torch.round(repl)
            s = torch.where(mask, repl, s)
        state.samples = s
        state.impulsive = mask if state.impulsive is None else state.impulsive | mask
        return state


def default_terms() -> list[Term]:
    """The default chain: photons, shot noise, read-out FPN, read noise, ADC, IMP (rate 0)."""
    return [Photons(), ShotNoise(), ReadoutFPN(), ReadNoise(), ADC(), ImpulsivePixels()]
