r"""Amplitude-gated fusion of filtered and raw depth (eq. 11 of Georgiev et al., IEEE SAS 2015).

Derivation of eq. (11) and of ``delta_A`` (the extracted text of the seed is garbled)
-----------------------------------------------------------------------------------
The extraction prints ``FPNAFAADA DDD )1( . (11)``: the symbols of
``D_A = delta_A D_F + (1 - delta_A) D_FPN`` read with subscripts pulled out of line
(``D_A``, ``delta_A``, ``D_F``, ``(1 - delta_A)``, ``D_FPN``). The surrounding text fixes the
meaning: "filtered output D_F and original data input D_FPN are fused in certain normalized
fraction (delta_A, 1 - delta_A) according to signal amplitudes A", i.e. a convex combination with
weight ``delta_A`` on the filtered depth. The weight is specified in words: "for very low amplitudes
(A <= 70), delta_A = 1, while for the range of amplitudes [70, 350], it decreases linearly between 1
and 0.2"; above 350 it stays at the end value 0.2 (continuity; strong signals carry less FPN,
Sec. IV-B: 25 % of the signal at low amplitude, under 5 % above the low-sensing range). Hence::

    delta_A(A) = 1                                          A <= low
               = 1 - (1 - floor) (A - low) / (high - low)   low < A < high
               = floor                                      A >= high

    D_A = delta_A(A) D_F + (1 - delta_A(A)) D              (eq. 11)

with ``low``, ``high``, ``floor`` = :data:`~tof_fpn_torch.constants.FUSION_LOW`,
:data:`~tof_fpn_torch.constants.FUSION_HIGH`, :data:`~tof_fpn_torch.constants.FUSION_FLOOR`
(70, 350, 0.2 in CamCube amplitude units). This is ``clamp`` of a line, so it is continuous,
monotone, and differentiable except at the two knots. Invalid pixels
(:func:`~tof_fpn_torch.runtime.valid_mask` of depth and amplitude) keep their raw depth.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .. import constants as K
from ._checks import check_fusion_inputs
from .validity import valid_mask

__all__ = ["AmplitudeFusion", "amplitude_fusion", "amplitude_weight"]


def _check_params(low: float, high: float, floor: float) -> None:
    for name, v in (("low", low), ("high", high), ("floor", floor)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"{name} must be a finite real number, got {v!r}")
    if not 0.0 <= low < high:
        raise ValueError(
            f"amplitude thresholds must satisfy 0 <= low < high, got low={low}, high={high}"
        )
    if not 0.0 <= floor <= 1.0:
        raise ValueError(f"floor must lie in [0, 1], got {floor!r}")


def amplitude_weight(
    amplitude: torch.Tensor,
    low: float = K.FUSION_LOW,
    high: float = K.FUSION_HIGH,
    floor: float = K.FUSION_FLOOR,
) -> torch.Tensor:
    """``delta_A``: 1 below ``low``, linear to ``floor`` at ``high``, ``floor`` above."""
    slope = (1.0 - floor) / (high - low)
    return torch.clamp(1.0 - slope * (amplitude - low), min=floor, max=1.0)


def _fuse(
    filtered: torch.Tensor,
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    low: float,
    high: float,
    floor: float,
) -> torch.Tensor:
    delta = amplitude_weight(amplitude, low, high, floor).to(depth.dtype)
    fused = depth + delta * (filtered - depth)
    return torch.where(valid_mask(depth, amplitude), fused, depth)


def amplitude_fusion(
    filtered: torch.Tensor,
    depth: torch.Tensor,
    amplitude: torch.Tensor,
    low: float = K.FUSION_LOW,
    high: float = K.FUSION_HIGH,
    floor: float = K.FUSION_FLOOR,
) -> torch.Tensor:
    """``delta_A D_F + (1 - delta_A) D`` (eq. 11), computed as ``D + delta_A (D_F - D)``.

    Args:
        filtered, depth, amplitude: (B, 1, H, W) float; invalid pixels (depth or amplitude, by
            :func:`~tof_fpn_torch.runtime.valid_mask`) return ``depth`` unchanged.
        low, high, floor: the ramp of ``delta_A`` (0 <= low < high, floor in [0, 1]).

    Example:
        >>> d = torch.full((1, 1, 1, 3), 2.0)
        >>> amplitude_fusion(d + 1, d, torch.tensor([[[[0.0, 210.0, float("nan")]]]]))
        tensor([[[[3.0000, 2.6000, 2.0000]]]])
    """
    check_fusion_inputs(filtered, depth, amplitude)
    _check_params(low, high, floor)
    return _fuse(filtered, depth, amplitude, low, high, floor)


class AmplitudeFusion(nn.Module):
    r"""Fuse filtered and raw depth by amplitude (eq. 11): strong filtering where the signal is weak.

    Args:
        low: amplitude up to which the filtered depth is used alone (``delta_A = 1``).
        high: amplitude from which ``delta_A = floor``.
        floor: weight of the filtered depth for strong signals, in [0, 1].

    Shape:
        - filtered, depth, amplitude: (B, 1, H, W) float.
        - Output: (B, 1, H, W). Invalid pixels keep ``depth``.

    Example:
        >>> fuse = AmplitudeFusion()
        >>> d = torch.full((1, 1, 2, 2), 2.0)
        >>> fuse(d + 1, d, torch.tensor([[[[0.0, 70.0], [210.0, 500.0]]]]))
        tensor([[[[3.0000, 3.0000],
                  [2.6000, 2.2000]]]])
    """

    __jit_ignored_attributes__ = ["bins"]

    def __init__(
        self, low: float = K.FUSION_LOW, high: float = K.FUSION_HIGH, floor: float = K.FUSION_FLOOR
    ) -> None:
        super().__init__()
        _check_params(low, high, floor)
        self.low = float(low)
        self.high = float(high)
        self.floor = float(floor)
        self.bins = None  # what a builder measured the thresholds on (AmplitudeBins), if any

    def extra_repr(self) -> str:
        return f"low={self.low}, high={self.high}, floor={self.floor}"

    def weight(self, amplitude: torch.Tensor) -> torch.Tensor:
        """``delta_A`` for an amplitude tensor."""
        return amplitude_weight(amplitude, self.low, self.high, self.floor)

    def forward(
        self, filtered: torch.Tensor, depth: torch.Tensor, amplitude: torch.Tensor
    ) -> torch.Tensor:
        check_fusion_inputs(filtered, depth, amplitude)
        return _fuse(filtered, depth, amplitude, self.low, self.high, self.floor)
