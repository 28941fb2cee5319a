"""The paper's depth-domain noise model: eq. (2) noise and the amplitude-dependent FPN of eq. (10).

Georgiev, Bregovic, Gotchev, "Fixed-pattern noise suppression in low-sensing environment of
Time-of-Flight devices", IEEE SAS 2015, Sec. II and IV-B.

Eq. (2): ``sigma_D^2 = lambda / A^2``
--------------------------------------
The depth variance is inversely proportional to the squared amplitude (Fig. 1). Derived from the
eq. (1) decoder (:mod:`tof_fpn_torch.sim.camera`): independent per-sample noise of variance ``v``
gives ``sigma_D^2 = (c_L / (4 pi f))^2 * 2 v / (N A^2)``, so
``lambda = (c_L / (4 pi f))^2 * 2 v / N`` (:func:`noise_lambda`). ``v`` contains the shot noise
of the offset, so the ``1 / A`` law holds where ``v`` does not grow with ``A``: offset dominated
by ambient light / dark signal, or read noise -- the low-sensing regime. Where the active signal
dominates the offset, ``v ~ A`` and ``sigma_D ~ 1 / sqrt(A)``.

Eq. (10): amplitude-dependent FPN (reconstructed; the seed's text is garbled)
-----------------------------------------------------------------------------
What survives of eq. (10) in the extraction is ``D_FPN``, ``D`` (twice), ``cos``, ``omega_FPN`` and
one ``A``; the Greek constants and operators were lost. The text fixes: (i) the FPN is added to the
depth, proportional to the depth ("25 % of the signal value"), as cosines at
``omega_FPN = {pi, 2 pi / 3}``; (ii) its intensity is a function of the amplitude with
``alpha = -3.966``, ``beta = 0.012``, ``gamma = 5.25``; (iii) it is "25 % of the signal value for
very low-sensed signals and less than 5 % for signals above the low-sensing environment"
(``A >= 300``). We write::

    D_FPN(y, x) = D(y, x) * (1 + k(A(y, x)) * p(x)),     p(x) = (1/K) sum_k cos(omega_k x + theta_k)

so ``|p| <= 1`` and ``k(A)`` is the peak FPN as a fraction of ``D``, and::

    k(A)^2 = beta * gamma * exp(alpha * A / A_LS),        A_LS = 300 (low-sensing threshold)
    k(A)   = sqrt(beta * gamma) * exp(alpha * A / (2 A_LS))

Why this form: ``sqrt(beta * gamma) = sqrt(0.063) = 0.2510`` is the "25 %" at ``A -> 0`` to three
digits, which no other combination of the three constants gives; ``alpha < 0`` is then the decay
of the FPN power per low-sensing range, ``k(300) = 0.251 e^{-1.983} = 3.46 % < 5 %``. The form is
monotone and bounded (a pixel with no light has a bounded FPN, the depth error of the raw model
saturates as the phase becomes uniform). Forms rejected: ``exp(alpha + gamma e^{-beta A})``
(``3.6 = 361 %`` at ``A = 0``), ``gamma A^alpha + beta`` and ``(beta A)^alpha gamma`` (unbounded
at ``A -> 0``), ``(gamma + alpha ln(beta A)) %`` (negative above ``A = 313``). With our
:func:`~tof_fpn_torch.sim.scenes.synthetic_scene` the form gives an FPN-only input PSNR close to
Table I's 24.51 dB (see docs/simulator.md for the measured figure and command). This is a
reconstruction; ``alpha``, ``beta``, ``gamma`` and ``A_LS`` are fields, so the shape can be refit.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .. import constants as K
from .camera import SPEED_OF_LIGHT_AIR, Camera, _as_float

__all__ = [
    "FPN_ALPHA",
    "FPN_BETA",
    "FPN_GAMMA",
    "LOW_SENSING_THRESHOLD",
    "DepthFPN",
    "add_depth_fpn",
    "add_depth_noise",
    "depth_noise_std",
    "fpn_intensity",
    "fpn_pattern",
    "noise_lambda",
    "noise_lambda_for_psnr",
]

# re-exported from the one place they are written
FPN_ALPHA: float = K.FPN_ALPHA
FPN_BETA: float = K.FPN_BETA
FPN_GAMMA: float = K.FPN_GAMMA
LOW_SENSING_THRESHOLD: float = K.LOW_SENSING_THRESHOLD


def _check_amp(amplitude: torch.Tensor) -> None:
    if amplitude.dim() != 4 or amplitude.shape[1] != 1:
        raise ValueError(f"amplitude must have shape (B, 1, H, W), got {list(amplitude.shape)}")
    if not amplitude.is_floating_point():
        raise ValueError(f"amplitude must be floating point, got dtype {amplitude.dtype}")
    bad = ~torch.isfinite(amplitude) | (amplitude < 0)
    if bool(bad.any()):
        raise ValueError(
            f"amplitude must be finite and >= 0, got {int(bad.sum())} NaN/inf/negative pixel(s)"
        )


def _check_depth_amp(depth: torch.Tensor, amplitude: torch.Tensor) -> None:
    if depth.dim() != 4 or depth.shape[1] != 1:
        raise ValueError(f"depth must have shape (B, 1, H, W), got {list(depth.shape)}")
    if not depth.is_floating_point():
        raise ValueError(f"depth must be floating point, got dtype {depth.dtype}")
    if amplitude.shape != depth.shape:
        raise ValueError(
            f"amplitude must have the shape of depth {list(depth.shape)}, got {list(amplitude.shape)}"
        )
    _check_amp(amplitude)
    if bool((depth < 0).any()):
        raise ValueError(
            f"depth must be >= 0 (0 or NaN mark invalid pixels), got min {float(depth.min())}"
        )


def fpn_intensity(
    amplitude: torch.Tensor,
    alpha: float = FPN_ALPHA,
    beta: float = FPN_BETA,
    gamma: float = FPN_GAMMA,
    amplitude_ref: float = LOW_SENSING_THRESHOLD,
) -> torch.Tensor:
    """``k(A) = sqrt(beta gamma) exp(alpha A / (2 A_ref))``: peak FPN as a fraction of depth.

    The reconstruction of eq. (10) (module docstring). Needs ``beta * gamma > 0`` and
    ``amplitude_ref > 0``; any shape.
    """
    if not (beta * gamma > 0.0 and math.isfinite(beta * gamma)):
        raise ValueError(f"beta * gamma must be finite and > 0, got beta={beta}, gamma={gamma}")
    if not (amplitude_ref > 0.0 and math.isfinite(amplitude_ref)):
        raise ValueError(f"amplitude_ref must be finite and > 0, got {amplitude_ref}")
    if not math.isfinite(alpha):
        raise ValueError(f"alpha must be finite, got {alpha}")
    return math.sqrt(beta * gamma) * torch.exp(amplitude * (alpha / (2.0 * amplitude_ref)))


def fpn_pattern(
    length: int,
    frequencies: list[float],
    phases: list[float],
    device: torch.device | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """``p(x) = (1/K) sum_k cos(omega_k x + theta_k)``, ``x = 0 .. length-1``, shape (length,)."""
    if len(frequencies) == 0 or len(frequencies) != len(phases):
        raise ValueError(
            f"frequencies and phases must be non-empty and of equal length, got "
            f"{len(frequencies)} and {len(phases)}"
        )
    x = torch.arange(length, device=device, dtype=torch.float64)
    p = torch.zeros(length, device=device, dtype=torch.float64)
    for i in range(len(frequencies)):
        p = p + torch.cos(x * frequencies[i] + phases[i])
    return (p / len(frequencies)).to(dtype)


def add_depth_fpn(
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    frequencies: list[float],
    phases: list[float],
    alpha: float = FPN_ALPHA,
    beta: float = FPN_BETA,
    gamma: float = FPN_GAMMA,
    amplitude_ref: float = LOW_SENSING_THRESHOLD,
    dim: int = -1,
) -> torch.Tensor:
    """Eq. (10): ``D_FPN = D (1 + k(A) p(x))``, stripes along ``dim`` (-1: columns, -2: rows).

    Args:
        depth: (B, 1, H, W) metres; invalid pixels (NaN or 0) stay as they are.
        amplitude: (B, 1, H, W), finite and >= 0.
        frequencies, phases: ``omega_k`` (rad/sample) and ``theta_k`` (rad) of ``p``.
        alpha, beta, gamma, amplitude_ref: parameters of :func:`fpn_intensity`.
        dim: -1 for a pattern varying along the width (vertical, column stripes), -2 for rows.

    Returns:
        A new (B, 1, H, W) tensor; the inputs are not modified.
    """
    _check_depth_amp(depth, amplitude)
    if dim != -1 and dim != -2:
        raise ValueError(f"dim must be -1 (column stripes) or -2 (row stripes), got {dim}")
    length = depth.shape[dim]
    p = fpn_pattern(length, frequencies, phases, depth.device, depth.dtype)
    p = p.view(1, 1, 1, length) if dim == -1 else p.view(1, 1, length, 1)
    k = fpn_intensity(amplitude, alpha, beta, gamma, amplitude_ref)
    return depth * (1.0 + k * p)


class DepthFPN(nn.Module):
    """Module form of :func:`add_depth_fpn` (eq. 10), parameters as attributes.

    Args:
        frequencies: ``omega_FPN``, default ``(2 pi / 3, pi)``.
        phases: ``theta_k`` (default zeros).
        alpha, beta, gamma: default :data:`~tof_fpn_torch.constants.FPN_ALPHA`, ``FPN_BETA``,
            ``FPN_GAMMA`` (Sec. IV-B).
        amplitude_ref: ``A_LS``, 300.
        axis: ``"columns"`` (vertical stripes) or ``"rows"``.

    Shape:
        depth, amplitude: (B, 1, H, W) -> (B, 1, H, W).
    """

    def __init__(
        self,
        frequencies: tuple[float, ...] = K.FPN_FREQUENCIES,
        phases: tuple[float, ...] | None = None,
        alpha: float = FPN_ALPHA,
        beta: float = FPN_BETA,
        gamma: float = FPN_GAMMA,
        amplitude_ref: float = LOW_SENSING_THRESHOLD,
        axis: str = "columns",
    ) -> None:
        super().__init__()
        freqs = [_as_float(w, "frequencies") for w in frequencies]
        if not freqs or any(not (0 < w <= math.pi + 1e-12) for w in freqs):
            raise ValueError(
                f"frequencies must be a non-empty list in (0, pi], got {frequencies!r}"
            )
        ph = [0.0] * len(freqs) if phases is None else [_as_float(p, "phases") for p in phases]
        if len(ph) != len(freqs):
            raise ValueError(f"phases must have {len(freqs)} entries, got {len(ph)}")
        if axis not in ("columns", "rows"):
            raise ValueError(f"axis must be 'columns' or 'rows', got {axis!r}")
        fpn_intensity(torch.zeros(1), alpha, beta, gamma, amplitude_ref)  # validates
        self.frequencies: list[float] = freqs
        self.phases: list[float] = ph
        self.alpha = float(alpha)
        self.beta = float(beta)
        self.gamma = float(gamma)
        self.amplitude_ref = float(amplitude_ref)
        self.dim = -1 if axis == "columns" else -2

    def intensity(self, amplitude: torch.Tensor) -> torch.Tensor:
        return fpn_intensity(amplitude, self.alpha, self.beta, self.gamma, self.amplitude_ref)

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        return add_depth_fpn(
            depth,
            amplitude,
            self.frequencies,
            self.phases,
            self.alpha,
            self.beta,
            self.gamma,
            self.amplitude_ref,
            self.dim,
        )

    def extra_repr(self) -> str:
        return (
            f"frequencies={self.frequencies}, alpha={self.alpha}, beta={self.beta}, "
            f"gamma={self.gamma}, amplitude_ref={self.amplitude_ref}, dim={self.dim}"
        )


def depth_noise_std(
    amplitude: torch.Tensor, lam: float, amplitude_floor: float = 1.0
) -> torch.Tensor:
    """Eq. (2): ``sigma_D = sqrt(lambda) / max(A, amplitude_floor)`` (metres)."""
    if not (lam >= 0.0 and math.isfinite(lam)):
        raise ValueError(f"lam must be finite and >= 0 (m^2 * amplitude^2), got {lam}")
    if not (amplitude_floor > 0.0 and math.isfinite(amplitude_floor)):
        raise ValueError(f"amplitude_floor must be finite and > 0, got {amplitude_floor}")
    return math.sqrt(lam) / torch.clamp(amplitude, min=amplitude_floor)


def add_depth_noise(
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    lam: float,
    *,
    amplitude_floor: float = 1.0,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """``D + sigma_D(A) xi`` with ``xi ~ N(0, 1)`` and ``sigma_D`` from eq. (2).

    Args:
        depth, amplitude: (B, 1, H, W); invalid depth (NaN or 0) is left as is.
        lam: ``lambda`` of eq. (2), m^2 (amplitude unit)^2; see :func:`noise_lambda`.
        amplitude_floor: amplitudes below it count as it (bounds the noise of dark pixels).
        generator: torch.Generator on the depth's device, for reproducible noise.
    """
    _check_depth_amp(depth, amplitude)
    sigma = depth_noise_std(amplitude, lam, amplitude_floor)
    xi = torch.randn(depth.shape, generator=generator, device=depth.device, dtype=depth.dtype)
    noisy = depth + sigma * xi
    invalid = ~torch.isfinite(depth) | (depth == 0)
    return torch.where(invalid, depth, noisy)


def noise_lambda(camera: Camera, offset: float | torch.Tensor) -> float | torch.Tensor:
    """``lambda`` of eq. (2) predicted for the raw simulator, amplitudes and offsets in DN.

    ``lambda = (c_L / (4 pi f))^2 * 2 v / N`` with the per-sample variance
    ``v = offset / g + (read_noise / g)^2 + 1/12`` (DN^2: shot noise of the offset charge, read
    noise, uniform quantisation), ``g`` the conversion gain. FPN and saturation are not included.
    """
    f = _as_float(camera.modulation_frequency, "modulation_frequency")
    g = _as_float(camera.conversion_gain, "conversion_gain")
    rn = _as_float(camera.read_noise, "read_noise")
    v = offset / g + (rn / g) ** 2 + 1.0 / 12.0
    return (SPEED_OF_LIGHT_AIR / (4 * math.pi * f)) ** 2 * 2.0 * v / camera.n_phases


def noise_lambda_for_psnr(
    reference: torch.Tensor,
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    target_psnr: float,
    *,
    amplitude_floor: float = 1.0,
    d_max: float = K.D_MAX,
) -> float:
    """``lambda`` such that ``add_depth_noise(depth, amplitude, lambda)`` has, in expectation, PSNR
    ``target_psnr`` (eq. 9) against ``reference``.

    The added noise is independent of ``depth - reference``, so the expected MSE is
    ``mean((depth - reference)^2) + lambda * mean(1 / max(A, floor)^2)`` over the valid pixels of
    ``reference``; solving for ``lambda`` gives a closed form (all images of the batch pooled).
    Use it to set the noise level of the paper's synthetic experiment (Table I, "noise added").

    Raises:
        ValueError: if ``depth`` alone is already below ``target_psnr`` (no lambda >= 0 reaches it).
    """
    _check_depth_amp(depth, amplitude)
    if reference.shape != depth.shape:
        raise ValueError(
            f"reference must have the shape of depth {list(depth.shape)}, got {list(reference.shape)}"
        )
    valid = torch.isfinite(reference) & (reference > 0) & torch.isfinite(depth)
    if not bool(valid.any()):
        raise ValueError("no valid pixel (finite reference > 0 and finite depth)")
    err = (depth - reference)[valid].double()
    mse0 = float((err * err).mean())
    inv_a2 = float((1.0 / torch.clamp(amplitude[valid].double(), min=amplitude_floor) ** 2).mean())
    target_mse = d_max * d_max / 10.0 ** (float(target_psnr) / 10.0)
    if target_mse < mse0:
        have = 10 * math.log10(d_max * d_max / mse0) if mse0 > 0 else math.inf
        raise ValueError(
            f"target_psnr {target_psnr} dB is above the PSNR of depth without noise ({have:.2f} dB)"
        )
    return (target_mse - mse0) / inv_a2
