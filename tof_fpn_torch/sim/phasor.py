"""The first DFT harmonic of the correlation samples (the phasor eq. (1) decodes) and a delay /
gain applied to it: what the phase effects of the simulator share."""

from __future__ import annotations

import math

import torch

from .camera import SPEED_OF_LIGHT_AIR, _as_float
from .terms import _num

__all__ = ["fundamental", "rotate_fundamental"]


def _angles(n: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    t = torch.arange(n, dtype=torch.float64, device=like.device) * (2 * math.pi / n)
    return torch.cos(t).to(like.dtype).view(1, n, 1, 1), torch.sin(t).to(like.dtype).view(
        1, n, 1, 1
    )


def fundamental(samples: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(Re X_1, Im X_1)`` of (B, N, H, W) samples, each (B, 1, H, W)."""
    c, s = _angles(samples.shape[1], samples)
    return (samples * c).sum(1, keepdim=True), -(samples * s).sum(1, keepdim=True)


def rotate_fundamental(samples: torch.Tensor, phase, scale=None) -> torch.Tensor:
    """Multiply the first harmonic by ``scale e^{j phase}`` (delay / gain of the modulated part);
    the offset and the other DFT bins stay. ``phase``, ``scale``: broadcastable to (B, 1, H, W)."""
    n = samples.shape[1]
    c, s = _angles(n, samples)
    xr, xi = fundamental(samples)
    cp, sp = torch.cos(phase), torch.sin(phase)
    if scale is not None:
        cp, sp = cp * scale, sp * scale
    yr, yi = xr * cp - xi * sp, xr * sp + xi * cp
    return samples + (2.0 / n) * ((yr - xr) * c - (yi - xi) * s)


def _stacked(values, like: torch.Tensor) -> torch.Tensor:
    """A 1-D tensor of ``values`` (floats or 0-d tensors, graph kept) like ``like``."""
    return torch.stack(
        [torch.as_tensor(_num(x, like), dtype=like.dtype, device=like.device) for x in values]
    )


def _phase_per_metre(camera) -> float:
    return 4.0 * math.pi * _as_float(camera.modulation_frequency, "f") / SPEED_OF_LIGHT_AIR
