"""Camera settings of the raw-level ToF simulator and the eq. (1) decoder.

Derivation of eq. (1) (garbled in the seed text)
-------------------------------------------------
A continuous-wave ToF pixel correlates the received light, delayed by the round trip ``2 D / c_L``,
with the reference modulation shifted by ``psi_n = 2 pi n / N`` (``n = 0 .. N-1``). For a sinusoidal
modulation of frequency ``f`` the correlation samples are::

    R_n = B + A cos(phi + 2 pi n / N),     phi = 4 pi f D / c_L

with ``B`` the offset (ambient + mean active signal) and ``A`` the modulation amplitude. Their
first DFT coefficient is::

    X_1 = sum_n R_n e^{-j 2 pi n / N}
        = B sum_n e^{-j 2 pi n/N}                                     (= 0 for N >= 2)
          + (A/2) e^{j phi} sum_n 1                                   (= N A e^{j phi} / 2)
          + (A/2) e^{-j phi} sum_n e^{-j 4 pi n / N}                  (= 0 for N >= 3)
        = (N A / 2) e^{j phi}

hence eq. (1) and the offset (the DFT bin 0)::

    phi = arg(X_1) mod 2 pi,     A = (2 / N) |X_1|,     B = (1 / N) sum_n R_n

and eq. (2)'s first part ``D = c_L phi / (4 pi f)``, unambiguous on ``[0, c_L / (2 f))`` (7.49 m
at 20 MHz, the paper's ``D_MAX = 7.5 m``). A pure sinusoid needs only ``N >= 3``; the paper (and
this code) require ``N >= 4``, which also keeps the DC and the second harmonic of a non-sinusoidal
correlation out of bin 1. The simulator uses a sinusoidal correlation.

Noise (eq. 2 derived): with independent per-sample noise of variance ``v`` (DN^2),
``Re X_1`` and ``Im X_1`` each get variance ``N v / 2``; the phase error is the component
orthogonal to ``X_1`` divided by ``|X_1| = N A / 2``, so
``var(phi) = 2 v / (N A^2)`` and ``sigma_D^2 = (c_L / (4 pi f))^2 * 2 v / (N A^2) = lambda / A^2``
(see :func:`tof_fpn_torch.sim.depth_model.noise_lambda`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch
from torch import nn

from .. import constants as K

__all__ = [
    "SPEED_OF_LIGHT_AIR",
    "Camera",
    "DepthFromSamples",
    "depth_from_samples",
    "unambiguous_range",
]

SPEED_OF_LIGHT_AIR: float = K.SPEED_OF_LIGHT_AIR  # re-exported: c / n_air, the paper's ``c_L``


def _as_float(value, name: str) -> float:
    """``float(value)`` for a Python number or a 0-d tensor, with a clear error otherwise."""
    if isinstance(value, torch.Tensor):
        if value.numel() != 1:
            raise ValueError(f"{name} must be a scalar, got a tensor of shape {list(value.shape)}")
        return float(value.detach())
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    return float(value)


def _check_range(value, name: str, low: float, *, strict: bool, unit: str = "") -> float:
    v = _as_float(value, name)
    ok = math.isfinite(v) and (v > low if strict else v >= low)
    if not ok:
        rel = ">" if strict else ">="
        raise ValueError(f"{name} must be finite and {rel} {low:g}{unit}, got {v!r}")
    return v


@dataclass
class Camera:
    """Operating settings and sensor specification of a continuous-wave ToF camera.

    Every field is a plain number (or a 0-d tensor when fitting) that can be read, changed with
    :func:`dataclasses.replace` and optimised. Electrons (e-) are the charge unit, DN the ADC code.

    Args:
        modulation_frequency: ``f`` in Hz (> 0). Default 20 MHz (PMD CamCube 2.0).
        n_phases: number ``N`` of correlation samples per depth frame, an int >= 4 (eq. 1).
        integration_time: exposure of each correlation sample in s (> 0). 2 ms is the paper's
            normal mode, 50-200 us its low-sensing captures.
        illumination_power: optical power of the modulated illumination in W (>= 0).
        ambient_irradiance: ambient (background) irradiance on the scene in the sensor's band,
            W/m^2 (>= 0).
        read_noise: read-out noise, e- rms per sample (>= 0).
        adc_bits: ADC resolution, an int in [1, 32]; codes are ``0 .. 2**adc_bits - 1``.
        conversion_gain: e- per DN (> 0).
        full_well: saturation charge in e- (> 0); charge above it is clipped.
    """

    modulation_frequency: float = K.CAMCUBE_MODULATION_FREQUENCY_HZ
    n_phases: int = 4
    integration_time: float = 2e-3
    illumination_power: float = 1.0
    ambient_irradiance: float = 0.1
    read_noise: float = 10.0
    adc_bits: int = 12
    conversion_gain: float = 25.0
    full_well: float = 100_000.0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> Camera:
        """Raise :class:`ValueError` for impossible settings; return ``self``."""
        _check_range(
            self.modulation_frequency, "modulation_frequency", 0.0, strict=True, unit=" Hz"
        )
        n = self.n_phases
        if isinstance(n, bool) or not isinstance(n, int) or n < 4:
            raise ValueError(f"n_phases must be an int >= 4 (eq. 1 needs N >= 4), got {n!r}")
        _check_range(self.integration_time, "integration_time", 0.0, strict=True, unit=" s")
        _check_range(self.illumination_power, "illumination_power", 0.0, strict=False, unit=" W")
        _check_range(self.ambient_irradiance, "ambient_irradiance", 0.0, strict=False)
        _check_range(self.read_noise, "read_noise", 0.0, strict=False, unit=" e-")
        b = self.adc_bits
        if isinstance(b, bool) or not isinstance(b, int) or not 1 <= b <= 32:
            raise ValueError(f"adc_bits must be an int in [1, 32], got {b!r}")
        _check_range(self.conversion_gain, "conversion_gain", 0.0, strict=True, unit=" e-/DN")
        _check_range(self.full_well, "full_well", 0.0, strict=True, unit=" e-")
        return self

    @property
    def max_code(self) -> int:
        """Largest ADC code, ``2**adc_bits - 1``."""
        return (1 << self.adc_bits) - 1

    @property
    def unambiguous_range(self) -> float:
        """``c_L / (2 f)`` in metres (7.49 m at 20 MHz)."""
        return unambiguous_range(_as_float(self.modulation_frequency, "modulation_frequency"))

    def as_dict(self) -> dict:
        """The fields as a ``{name: value}`` dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def unambiguous_range(modulation_frequency: float = K.CAMCUBE_MODULATION_FREQUENCY_HZ) -> float:
    """Largest depth ``c_L / (2 f)`` (m) that eq. (1) recovers without phase wrapping."""
    f = _check_range(modulation_frequency, "modulation_frequency", 0.0, strict=True, unit=" Hz")
    return SPEED_OF_LIGHT_AIR / (2.0 * f)


def _dft_weights(n: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(3, N) rows: ``cos(2 pi n/N)``, ``-sin(2 pi n/N)``, ``1/N`` (Re X_1, Im X_1, offset)."""
    # angles in float64 so cos(pi), sin(pi) are exact to the working precision
    theta = torch.arange(n, dtype=torch.float64, device=device) * (2.0 * math.pi / n)
    w = torch.stack([torch.cos(theta), -torch.sin(theta), torch.full_like(theta, 1.0 / n)])
    # exact zeros (cos(pi/2), sin(pi), ...) so a flat pixel decodes to exactly A = 0, D = 0
    w = torch.where(w.abs() < 1e-12, torch.zeros_like(w), w)
    return w.to(dtype)


def _decode(
    samples: torch.Tensor, weights: torch.Tensor, modulation_frequency: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    b, n, h, w = samples.shape
    # one pass over the samples: (3, N) @ (B, N, H*W) -> (B, 3, H*W)
    proj = torch.matmul(weights, samples.reshape(b, n, h * w)).view(b, 3, h, w)
    real, imag, offset = proj[:, 0:1], proj[:, 1:2], proj[:, 2:3]
    phase = torch.remainder(torch.atan2(imag, real), 2.0 * math.pi)
    c_l = K.SPEED_OF_LIGHT_AIR
    depth = phase * (c_l / (4.0 * math.pi * modulation_frequency))
    amplitude = torch.hypot(real, imag) * (2.0 / n)
    return depth, amplitude, offset


def _check_samples(samples: torch.Tensor, modulation_frequency: float) -> None:
    if samples.dim() != 4:
        raise ValueError(
            "samples must have shape (B, N, H, W) with the N correlation samples as channels, "
            f"got shape {list(samples.shape)}"
        )
    if not samples.is_floating_point():
        raise ValueError(f"samples must be floating point, got dtype {samples.dtype}")
    if samples.shape[1] < 4:
        raise ValueError(
            f"samples must hold N >= 4 correlation samples, got N = {samples.shape[1]}"
        )
    if not (modulation_frequency > 0.0 and math.isfinite(modulation_frequency)):
        raise ValueError(
            f"modulation_frequency must be finite and > 0 Hz, got {modulation_frequency}"
        )


def depth_from_samples(
    samples: torch.Tensor, modulation_frequency: float = K.CAMCUBE_MODULATION_FREQUENCY_HZ
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Depth, amplitude and offset from N correlation samples by eq. (1).

    ``phase = arg(sum_n R_n e^{-j 2 pi n/N}) mod 2 pi``, ``A = (2/N) |sum_n R_n e^{-j 2 pi n/N}|``,
    ``B = mean_n R_n`` and ``D = c_L phase / (4 pi f)`` (derivation in the module docstring).

    Args:
        samples: (B, N, H, W) float, ``R_n`` for reference shifts ``2 pi n / N``, N >= 4.
        modulation_frequency: ``f`` in Hz.

    Returns:
        ``(depth, amplitude, offset)``, each (B, 1, H, W): depth in metres in
        ``[0, c_L / (2 f))``, amplitude and offset in the unit of ``samples``. A pixel whose
        samples are all equal (no modulation, e.g. a dead pixel) gets amplitude 0 and depth 0,
        the usual "invalid" code (exactly for N = 4 and 8, whose DFT weights are exact; other N
        leave a rounding-level amplitude and an arbitrary phase). Non-finite samples give NaN.
    """
    _check_samples(samples, modulation_frequency)
    weights = _dft_weights(samples.shape[1], samples.device, samples.dtype)
    return _decode(samples, weights, modulation_frequency)


class DepthFromSamples(nn.Module):
    """Module form of :func:`depth_from_samples` with the DFT weights as buffers.

    Args:
        n_phases: N, number of correlation samples (>= 4).
        modulation_frequency: ``f`` in Hz.

    Shape:
        - Input: (B, N, H, W)
        - Output: three (B, 1, H, W) tensors: depth (m), amplitude, offset.
    """

    def __init__(
        self, n_phases: int = 4, modulation_frequency: float = K.CAMCUBE_MODULATION_FREQUENCY_HZ
    ) -> None:
        super().__init__()
        if isinstance(n_phases, bool) or not isinstance(n_phases, int) or n_phases < 4:
            raise ValueError(f"n_phases must be an int >= 4, got {n_phases!r}")
        f = _check_range(modulation_frequency, "modulation_frequency", 0.0, strict=True, unit=" Hz")
        self.n_phases = n_phases
        self.modulation_frequency = f
        self.register_buffer("weights", _dft_weights(n_phases, torch.device("cpu"), torch.float64))

    def forward(self, samples: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        _check_samples(samples, self.modulation_frequency)
        if samples.shape[1] != self.n_phases:
            raise ValueError(
                f"samples must have N = {self.n_phases} channels (n_phases of this module), "
                f"got shape {list(samples.shape)}"
            )
        weights = self.weights.to(device=samples.device, dtype=samples.dtype)
        return _decode(samples, weights, self.modulation_frequency)

    def extra_repr(self) -> str:
        return f"n_phases={self.n_phases}, modulation_frequency={self.modulation_frequency:g}"
