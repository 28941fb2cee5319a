"""Depth <-> complex phasor helpers shared by the complex-domain corrections (torch only).

A continuous-wave ToF pixel measures ``z = A e^{j phi}``, ``phi = 4 pi f D / c_L``. A read-out offset
is additive in ``z``; :func:`phasor` builds the two channels ``(Re z, Im z)`` from depth and
amplitude and :func:`depth_from_phase_change` turns a corrected phasor back into depth by the
wrapped phase change ``angle(z' conj(z))`` (so a depth on another branch, e.g. unwrapped
multi-frequency depth, keeps its branch unless ``wrap``). Used by
:func:`~tof_fpn_torch.runtime.destripe` (``domain="complex"``) and
:class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`; TorchScript- and ONNX-clean.
"""

import math

import torch

from .. import constants as K

__all__ = ["depth_from_phase_change", "metres_per_radian", "phasor", "ray_norm"]


def metres_per_radian(modulation_frequency_hz: float) -> float:
    """``c_L / (4 pi f)``: the depth of one radian of phase."""
    return K.SPEED_OF_LIGHT_AIR / (4.0 * math.pi * modulation_frequency_hz)


def phasor(depth: torch.Tensor, amplitude: torch.Tensor, scale: float) -> torch.Tensor:
    """``(A cos phi, A sin phi)`` concatenated on dim 1, ``phi = depth / scale``: (N, 2, H, W) from
    (N, 1, H, W) ``depth`` and ``amplitude`` (zero them at invalid pixels first)."""
    phase = depth * (1.0 / scale)
    return torch.cat([amplitude * torch.cos(phase), amplitude * torch.sin(phase)], 1)


def depth_from_phase_change(
    depth: torch.Tensor, z: torch.Tensor, zc: torch.Tensor, scale: float, wrap: bool
) -> torch.Tensor:
    """``depth + scale * angle(zc conj(z))`` for (N, 2, H, W) phasors ``z`` (of ``depth``) and
    ``zc`` (corrected), re-wrapped into ``[0, 2 pi scale)`` when ``wrap``."""
    re, im = z[:, :1], z[:, 1:]
    re2, im2 = zc[:, :1], zc[:, 1:]
    dphi = torch.atan2(im2 * re - re2 * im, re2 * re + im2 * im)
    y = depth + scale * dphi
    if wrap:
        y = torch.remainder(y, 2.0 * math.pi * scale)
    return y


def ray_norm(
    height: int, width: int, focal_length_px: float, dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """(H, W) length of each pixel's ray per unit of depth along the optical axis: a pinhole with
    focal length ``focal_length_px`` (pixels) and the principal point at the frame centre,
    ``sqrt(1 + ((x - (W - 1) / 2)^2 + (y - (H - 1) / 2)^2) / f^2)``."""
    x = (torch.arange(width, dtype=dtype, device=device) - (width - 1) / 2.0) / focal_length_px
    y = (torch.arange(height, dtype=dtype, device=device) - (height - 1) / 2.0) / focal_length_px
    return torch.sqrt(1.0 + y[:, None] * y[:, None] + x[None, :] * x[None, :])
