"""Physical effects beyond the default chain: the diagnosis catalogue as simulator terms.

Each class is a :class:`~tof_fpn_torch.sim.terms.Term` (a dataclass with a fixed ``name`` and
numeric fields in physical units; fields may be 0-d tensors with ``requires_grad`` for fitting),
usable in any :class:`~tof_fpn_torch.sim.Simulation`. :func:`with_effect` inserts one at its place
in the chain (``STAGE``). All act on the correlation samples in e- (before :class:`ADC`).

Phase effects act on the first DFT harmonic of the samples (``X_1 = (N A/2) e^{j phi}``, the part
eq. (1) decodes): a delay ``delta`` (m) rotates it by ``4 pi f delta / c_L``, which moves the
decoded depth by exactly ``delta`` for a sinusoidal correlation and leaves the offset alone.

Catalogue name -> class: physics (parameters):

* ``fpn_pattern`` -> :class:`FPNPattern`: column / row delays of the demodulation clock tree, any
  spectrum (profiles in m, or ``rms_*`` in m with an AR(1) ``correlation``);
* ``amplitude_bias`` -> :class:`AmplitudeBias`: signal-dependent delay ``b A_ref / (A + A_ref)``
  (b in m, A_ref in e-), or a curve in ``ln A`` through given points;
* ``temporal_drift`` -> :class:`TemporalDrift`: warm-up delay ``D (1 - e^{-t/tau})`` (m, s) and
  light output ``1 + a (1 - e^{-t/tau})``;
* ``noise_floor`` -> :class:`PhaseJitter`: per-pixel, per-frame clock jitter (depth-equivalent
  rms, m);
* ``cyclic_error`` -> :class:`CyclicError`: correlation harmonics ``alpha_h cos(h psi) + beta_h
  sin(h psi)`` (relative to the fundamental);
* ``vignetting`` -> :class:`~tof_fpn_torch.sim.optics.Vignetting`: lens fall-off ``1 + a2 r^2 +
  a4 r^4`` (r in half-diagonals from a centre in px);
* ``pixel_gain`` -> :class:`~tof_fpn_torch.sim.optics.PixelGain`: photo-response non-uniformity
  (relative rms, fixed map);
* ``flying_pixels`` -> :class:`~tof_fpn_torch.sim.optics.LensBlur`: Gaussian PSF (px) mixing the
  returns of neighbouring pixels at depth edges;
* ``saturation`` -> :class:`~tof_fpn_torch.sim.optics.Saturation`: full-well / anti-blooming clip
  of every sample (e-, knee e-);
* ``multipath`` -> :class:`~tof_fpn_torch.sim.multipath.Multipath`: diffuse interreflection, a
  second return of the scene-mean phasor delayed by an extra path (relative strength, m).

``impulsive_pixels`` is :class:`~tof_fpn_torch.sim.readout.ImpulsivePixels`; ``phase_wrapping`` is
the decoder's own folding at ``camera.modulation_frequency`` (every simulation wraps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from .camera import _as_float, _check_range
from .cyclic import CyclicError
from .phasor import _phase_per_metre, _stacked, fundamental, rotate_fundamental
from .terms import SimState, Term, _num, _randn

__all__ = [
    "STAGE",
    "AmplitudeBias",
    "CyclicError",
    "FPNPattern",
    "PhaseJitter",
    "student_t",
    "TemporalDrift",
    "fundamental",
    "rotate_fundamental",
    "with_effect",
]

#: position of every term in the chain (lower runs first)
STAGE: dict[str, int] = {
    "photons": 0,
    "multipath": 5,
    "fpn_pattern": 10,
    "temporal_drift": 12,
    "noise_floor": 13,
    "cyclic_error": 20,
    "vignetting": 30,
    "pixel_gain": 31,
    "flying_pixels": 32,
    "edge_mixing": 33,
    "amplitude_bias": 35,
    "shot_noise": 40,
    "readout_fpn": 50,
    "pixel_offset": 51,
    "read_noise": 60,
    "saturation": 65,
    "adc": 70,
    "impulsive": 80,
}


def _profile(values, length: int, what: str, like: torch.Tensor) -> torch.Tensor:
    p = values if isinstance(values, torch.Tensor) else torch.tensor(values, dtype=torch.float64)
    p = p.to(device=like.device, dtype=like.dtype).reshape(-1)
    if p.numel() != length:
        raise ValueError(f"FPNPattern.{what} has {p.numel()} entries, the frame {length}")
    return p


def _ar1(length: int, rho: float, gen: torch.Generator) -> torch.Tensor:
    xi = torch.randn(length, generator=gen, dtype=torch.float64)
    out = torch.empty_like(xi)
    out[0] = xi[0]
    for i in range(1, length):
        out[i] = rho * out[i - 1] + math.sqrt(1 - rho * rho) * xi[i]
    out = out - out.mean()
    return out / out.std().clamp_min(1e-12)


@dataclass
class FPNPattern(Term):
    """Column- and row-wise delays (m): the skew of the demodulation clock along its tree; and a
    delay of each pixel (its own tap timing, a calibration's per-pixel phase offset).

    A column ``x`` demodulates ``delta_c(x)`` later, a row ``y`` ``delta_r(y)`` later: the first
    harmonic turns by ``4 pi f (delta_c(x) + delta_r(y)) / c_L``, so the depth moves by that many
    metres at any amplitude (unlike :class:`~tof_fpn_torch.sim.ReadoutFPN`'s read-out offsets,
    whose depth error falls as ``1 / A``). Any spectrum: broadband, periodic or random.

    Args:
        column_profile, row_profile: explicit delays (m), one per column / row, or ``None``.
        rms_columns, rms_rows: otherwise a random profile of this rms (m) from ``seed``,
            an AR(1) sequence with coefficient ``correlation`` in [0, 1) (0: white).
        rms_pixels: a random delay of each pixel (m rms, white, from ``seed``; 0: none), the
            same in every frame.
        correlation: neighbour correlation of the random profiles.
        seed: seed of the random profiles (the same in every frame).
    """

    column_profile: object = None
    row_profile: object = None
    rms_columns: float = 0.0
    rms_rows: float = 0.0
    correlation: float = 0.0
    seed: int = 11
    rms_pixels: float = 0.0
    name: str = field(default="fpn_pattern", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> FPNPattern:
        _check_range(self.rms_columns, "FPNPattern.rms_columns", 0.0, strict=False, unit=" m")
        _check_range(self.rms_rows, "FPNPattern.rms_rows", 0.0, strict=False, unit=" m")
        _check_range(self.rms_pixels, "FPNPattern.rms_pixels", 0.0, strict=False, unit=" m")
        c = _check_range(self.correlation, "FPNPattern.correlation", 0.0, strict=False)
        if c >= 1:
            raise ValueError(f"FPNPattern.correlation must be in [0, 1), got {c!r}")
        return self

    def profiles(self, h: int, w: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Column (W,) and row (H,) delays in metres."""
        gen = torch.Generator().manual_seed(int(self.seed))
        rho = _as_float(self.correlation, "correlation")
        out = []
        for prof, rms, n, what in (
            (self.column_profile, self.rms_columns, w, "column_profile"),
            (self.row_profile, self.rms_rows, h, "row_profile"),
        ):
            if prof is not None:
                out.append(_profile(prof, n, what, like))
            else:
                r = _ar1(n, rho, gen).to(device=like.device, dtype=like.dtype)
                out.append(r * _num(rms, like))
        return out[0], out[1]

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        _, _, h, w = s.shape
        col, row = self.profiles(h, w, s)
        delay = col.view(1, 1, 1, w) + row.view(1, 1, h, 1)
        if float(self.rms_pixels) > 0:
            gen = torch.Generator().manual_seed(int(self.seed) + 1)
            pix = torch.randn(h, w, generator=gen, dtype=torch.float64).to(s)
            delay = delay + pix.view(1, 1, h, w) * _num(self.rms_pixels, s)
        state.samples = rotate_fundamental(s, delay * _phase_per_metre(state.camera))
        return state


@dataclass
class AmplitudeBias(Term):
    """Signal-dependent delay: ``delta(A) = b A_ref / (A + A_ref)`` (m) at amplitude ``A`` (e-),
    or any curve through given points.

    The demodulation of a weak photocurrent lags (charge transfer slower at low charge): the
    depth reads ``b`` too far at ``A << A_ref`` and the bias fades above ``A_ref``. A camera's
    bias has its own shape: with ``knots`` (amplitudes in e-, increasing) and ``delays`` (m, one
    per knot) the delay is instead the piecewise-linear interpolation in ``ln A`` through those
    points, constant beyond the first and last knot (``delay`` and ``reference`` are then
    unused).

    Args:
        delay: ``b`` in metres (either sign).
        reference: ``A_ref`` in e- of amplitude (> 0).
        knots: amplitudes (e-, > 0, increasing) of the curve's points; empty: the hyperbola.
        delays: the delay (m) at each knot (floats or 0-d tensors).
    """

    delay: float = 0.0
    reference: float = 1000.0
    knots: tuple = ()
    delays: tuple = ()
    name: str = field(default="amplitude_bias", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> AmplitudeBias:
        _as_float(self.delay, "AmplitudeBias.delay")
        _check_range(self.reference, "AmplitudeBias.reference", 0.0, strict=True, unit=" e-")
        if len(self.knots) != len(self.delays) or len(self.knots) == 1:
            raise ValueError(
                "AmplitudeBias.knots and .delays must have the same length (0, or >= 2), got "
                f"{len(self.knots)} and {len(self.delays)}"
            )
        k = [_as_float(x, "AmplitudeBias.knots") for x in self.knots]
        if any(x <= 0 for x in k) or any(b <= a for a, b in zip(k, k[1:], strict=False)):
            raise ValueError(f"AmplitudeBias.knots must be > 0 and increasing, got {k}")
        return self

    def bias(self, amp: torch.Tensor) -> torch.Tensor:
        """The delay (m) at amplitudes ``amp`` (e-)."""
        if not self.knots:
            ref = _num(self.reference, amp)
            return _num(self.delay, amp) * ref / (amp + ref)
        u = torch.log(amp.clamp_min(1e-12))
        t = [math.log(float(x)) for x in self.knots]
        out = _num(self.delays[0], amp) * torch.ones_like(u)
        for j in range(1, len(t)):  # each segment adds its change, linear in ln A
            step = _num(self.delays[j], amp) - _num(self.delays[j - 1], amp)
            out = out + step * ((u - t[j - 1]) / (t[j] - t[j - 1])).clamp(0.0, 1.0)
        return out

    def apply(self, state: SimState) -> SimState:
        s = state.samples
        xr, xi = fundamental(s)
        amp = torch.sqrt(xr * xr + xi * xi + 1e-12) * (2.0 / s.shape[1])
        state.samples = rotate_fundamental(s, self.bias(amp) * _phase_per_metre(state.camera))
        return state


@dataclass
class TemporalDrift(Term):
    """Warm-up drift: delay ``D (1 - e^{-t/tau})`` (m) and light output ``1 + a (1 - e^{-t/tau})``.

    Frame ``f`` of a run is at ``t = f * frame_interval`` (s). Args: ``depth_step`` D (m),
    ``amplitude_step`` a (relative, > -1), ``time_constant`` tau (s, > 0), ``frame_interval`` (s).
    A drift of any shape instead: ``frame_delays`` (m) and ``frame_light`` (relative change,
    > -1), one per frame of the run (then the warm-up curve is unused).
    """

    depth_step: float = 0.0
    amplitude_step: float = 0.0
    time_constant: float = 1.0
    frame_interval: float = 1.0 / 30.0
    frame_delays: tuple = ()
    frame_light: tuple = ()
    name: str = field(default="temporal_drift", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> TemporalDrift:
        _as_float(self.depth_step, "TemporalDrift.depth_step")
        if _as_float(self.amplitude_step, "TemporalDrift.amplitude_step") <= -1:
            raise ValueError("TemporalDrift.amplitude_step must be > -1")
        _check_range(self.time_constant, "TemporalDrift.time_constant", 0.0, strict=True, unit=" s")
        _check_range(self.frame_interval, "TemporalDrift.frame_interval", 0.0, strict=True)
        if len(self.frame_delays) != len(self.frame_light):
            raise ValueError(
                "TemporalDrift.frame_delays and .frame_light must have one entry per frame each, "
                f"got {len(self.frame_delays)} and {len(self.frame_light)}"
            )
        if any(_as_float(x, "TemporalDrift.frame_light") <= -1 for x in self.frame_light):
            raise ValueError("TemporalDrift.frame_light entries must be > -1")
        for x in self.frame_delays:
            _as_float(x, "TemporalDrift.frame_delays")
        return self

    def curve(self, times: torch.Tensor) -> torch.Tensor:
        """``1 - exp(-t / tau)`` at ``times`` (s)."""
        return 1.0 - torch.exp(-times / _num(self.time_constant, times))

    def apply(self, state: SimState) -> SimState:
        s = state.expand().samples
        b = s.shape[0]
        frame = torch.arange(b, device=s.device, dtype=s.dtype) % state.frames
        if self.frame_delays:
            if len(self.frame_delays) < state.frames:
                raise ValueError(
                    f"TemporalDrift has {len(self.frame_delays)} frame delays, the run "
                    f"{state.frames} frames"
                )
            idx = frame.long()
            d = _stacked(self.frame_delays, s)[idx].view(b, 1, 1, 1)
            g = _stacked(self.frame_light, s)[idx].view(b, 1, 1, 1)
            state.samples = rotate_fundamental(s, d * _phase_per_metre(state.camera), 1.0 + g)
            return state
        u = self.curve(frame * _as_float(self.frame_interval, "frame_interval")).view(b, 1, 1, 1)
        phase = u * _num(self.depth_step, s) * _phase_per_metre(state.camera)
        state.samples = rotate_fundamental(s, phase, 1.0 + u * _num(self.amplitude_step, s))
        return state


@dataclass
class PhaseJitter(Term):
    """Clock jitter: every pixel of every frame is delayed by an independent ``N(0, sigma^2)``
    (``sigma`` in m, depth-equivalent): a depth noise floor that does not fall with amplitude.
    ``dof`` (> 2, default infinite: Gaussian): the delays are Student-t with ``dof`` degrees of
    freedom scaled to the sd ``sigma`` (a heavy-tailed floor: rare large delays)."""

    sigma: float = 0.0
    dof: float = math.inf
    name: str = field(default="noise_floor", init=False)

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> PhaseJitter:
        _check_range(self.sigma, "PhaseJitter.sigma", 0.0, strict=False, unit=" m")
        nu = _as_float(self.dof, "PhaseJitter.dof")
        if not nu > 2:
            raise ValueError(f"PhaseJitter.dof must be > 2 (a finite sd), got {nu}")
        return self

    def apply(self, state: SimState) -> SimState:
        s = state.expand().samples
        b, _, h, w = s.shape
        nu = float(self.dof)
        if math.isinf(nu):
            xi = _randn((b, 1, h, w), state.generator, s)
        else:
            xi = student_t((b, 1, h, w), nu, state.generator, s) * math.sqrt((nu - 2) / nu)
        state.samples = rotate_fundamental(
            s, xi * (_num(self.sigma, s) * _phase_per_metre(state.camera))
        )
        return state


def student_t(shape, dof: float, generator: torch.Generator, like: torch.Tensor) -> torch.Tensor:
    """Student-t variates with ``dof`` (> 0) degrees of freedom on ``like``'s device and dtype,
    by Bailey's polar method ("Polar generation of random variates with the t-distribution",
    Math. Comp. 62, 1994): ``U, V`` uniform on (-1, 1) with ``W = U^2 + V^2 < 1``, then
    ``T = U sqrt(dof (W^(-2 / dof) - 1) / W)``."""
    n = math.prod(shape)
    out = torch.empty(n, device=like.device, dtype=like.dtype)
    filled = 0
    while filled < n:
        m = 2 * (n - filled) + 16  # pi / 4 of the pairs are kept
        u = torch.empty(2, m, device=like.device, dtype=like.dtype).uniform_(
            -1, 1, generator=generator
        )
        w = (u * u).sum(0)
        ok = (w < 1) & (w > 0)
        t = u[0][ok] * torch.sqrt(dof * (w[ok] ** (-2.0 / dof) - 1) / w[ok])
        take = t[: n - filled]
        out[filled : filled + take.numel()] = take
        filled += take.numel()
    return out.view(shape)


def with_effect(sim, term: Term):
    """A copy of ``sim`` with ``term`` inserted at its place in the chain (:data:`STAGE`), or
    replacing the term of the same name."""
    from .simulator import Simulation

    terms = [t for t in sim.terms if t.name != term.name]
    rank = STAGE.get(term.name, 50)
    pos = len(terms)
    for i, t in enumerate(terms):
        if STAGE.get(t.name, 50) > rank:
            pos = i
            break
    terms.insert(pos, term)
    return Simulation(sim.camera, terms)
