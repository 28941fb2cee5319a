"""Read-out terms of the raw-level ToF simulator: column / row FPN, ADC, impulsive pixels.

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
from dataclasses import dataclass, field

import torch

from .. import constants as K
from .camera import _as_float, _check_range
from .terms import Photons, ReadNoise, ShotNoise, SimState, Term, _num, _owned

__all__ = ["ADC", "ImpulsivePixels", "PixelOffset", "ReadoutFPN", "default_terms"]


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
        offset_map: optional explicit offsets added to ``o_n(x)``, e-, shape (N, length) (e.g.
            a measured or fitted pattern); None: none.
        gain_map: optional explicit gains added to ``g_n(x)``, relative, shape (N, length).
    """

    frequencies: tuple[float, ...] = K.FPN_FREQUENCIES
    offset_amplitudes: tuple[float, ...] = (40.0, 40.0)
    gain_amplitudes: tuple[float, ...] = (0.002, 0.002)
    spatial_phases: tuple[float, ...] = (0.0, 0.0)
    sample_phase: float = 0.25 * math.pi
    random_offset: float = 10.0
    random_gain: float = 0.0005
    axis: str = "columns"
    seed: int = 20150413
    offset_map: object = None
    gain_map: object = None
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
        for nm, extra in (("offset_map", self.offset_map), ("gain_map", self.gain_map)):
            if extra is None:
                continue
            m = torch.as_tensor(extra).to(device=device, dtype=dtype)
            if tuple(m.shape) != (n, length):
                raise ValueError(
                    f"ReadoutFPN.{nm} must be (N, length) = ({n}, {length}), got {list(m.shape)}"
                )
            if nm == "offset_map":
                offsets = offsets + m
            else:
                gains = gains + m
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
class PixelOffset(Term):
    """A fixed complex offset per pixel on the decoded phasor (dark-signal non-uniformity of the
    demodulating pixel: the two taps' charges do not cancel): sample ``n`` of pixel ``p`` gets
    ``c_p cos(2 pi n / N) + d_p sin(2 pi n / N)`` e-, so ``(2 / N) X_1`` moves by ``c_p - j
    d_p``; ``c_p``, ``d_p`` i.i.d. N(0, ``sd``^2), the same in every frame (from ``seed``).
    Its depth error is ``|O| / A`` radians at most: it grows as the amplitude falls; the
    amplitude moves by the offset's radial part (not in proportion to the amplitude, as a
    gain would).

    Args:
        sd: rms of each component (e-, >= 0).
        seed: seed of the map.
    """

    sd: float = 0.0
    seed: int = 11
    name: str = field(default="pixel_offset", init=False)

    def __post_init__(self) -> None:
        _check_range(self.sd, "PixelOffset.sd", 0.0, strict=False, unit=" e-")

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        _, n, h, w = s.shape
        gen = torch.Generator().manual_seed(int(self.seed))
        c = torch.randn((2, h, w), generator=gen, dtype=torch.float64).to(s.device, s.dtype)
        th = torch.arange(n, device=s.device, dtype=s.dtype).view(1, n, 1, 1) * (2 * math.pi / n)
        off = c[0].view(1, 1, h, w) * torch.cos(th) + c[1].view(1, 1, h, w) * torch.sin(th)
        state.samples = s + _num(self.sd, s) * off
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
