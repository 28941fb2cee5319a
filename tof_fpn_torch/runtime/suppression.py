r"""FPN suppression stage: notch filtering plus amplitude-gated fusion (Georgiev et al., Sec. III-IV).

``FPNSuppression`` = :class:`~tof_fpn_torch.runtime.FPNFilter` followed (``adaptive=True``) by
:class:`~tof_fpn_torch.runtime.AmplitudeFusion` (eq. 11). It takes taps; to design them, use
:func:`tof_fpn_torch.build.suppression_from_design` (default ``{20, 0.14}``, the paper's best
adaptive result in Table I) or :func:`tof_fpn_torch.build.suppression_from_data`.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .. import constants as K
from ._checks import check_image, check_same_shape
from .fpn_filter import FPNFilter, _tracing
from .fusion import AmplitudeFusion, _fuse
from .validity import all_valid, valid_mask

__all__ = ["FPNSuppression"]


class FPNSuppression(nn.Module):
    r"""Fixed-pattern-noise suppression of ToF depth: notch FIR + amplitude fusion.

    Args:
        taps: notch filter taps (see :class:`FPNFilter`).
        dim: ``-1`` (column stripes), ``-2`` (row stripes) or ``(-2, -1)``.
        adaptive: fuse with the raw depth by amplitude (eq. 11); else return the filtered depth.
        low, high, floor: :class:`AmplitudeFusion` parameters.
        border, trainable, order, rho, notches, compensated: see :class:`FPNFilter`.

    Shape:
        - depth: (B, 1, H, W) float; invalid pixels (NaN, +-inf, <= 0, or an amplitude that is NaN,
          inf or negative) are returned unchanged.
        - amplitude: (B, 1, H, W) float.
        - Output: (B, 1, H, W).

    Example:
        >>> m = FPNSuppression(torch.tensor([0.25, 0.5, 0.25]))
        >>> m(torch.rand(1, 1, 32, 48) + 1.0, torch.full((1, 1, 32, 48), 100.0)).shape
        torch.Size([1, 1, 32, 48])
    """

    __jit_ignored_attributes__ = ["estimate"]
    __jit_unused_properties__ = ["design"]

    def __init__(
        self,
        taps,
        dim: int | tuple[int, ...] = -1,
        adaptive: bool = True,
        low: float = K.FUSION_LOW,
        high: float = K.FUSION_HIGH,
        floor: float = K.FUSION_FLOOR,
        border: str = "reflect",
        trainable: bool = False,
        *,
        order: int | None = None,
        rho: float | None = None,
        notches: tuple[float, ...] = (),
        compensated: bool = False,
    ) -> None:
        super().__init__()
        self.filter = FPNFilter(
            taps,
            dim=dim,
            border=border,
            trainable=trainable,
            order=order,
            rho=rho,
            notches=notches,
            compensated=compensated,
        )
        self.fusion = AmplitudeFusion(low, high, floor)
        self.adaptive = bool(adaptive)
        self.estimate = None  # the stripe estimate, when a builder made this module from data

    @property
    def design(self):
        """The offline design of the filter (when a builder made this module), else None."""
        return self.filter.design

    def extra_repr(self) -> str:
        return f"adaptive={self.adaptive}"

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        check_image(depth, "depth", 1)
        check_image(amplitude, "amplitude", 1)
        check_same_shape(amplitude, depth, "amplitude", "depth")
        mask: torch.Tensor | None = None
        if _tracing():
            mask = valid_mask(depth, amplitude)
        elif amplitude.numel() > 0:  # one min/max each instead of a mask when all are valid
            lo, hi = torch.aminmax(amplitude)
            if not (bool(lo >= 0) and bool(hi < math.inf)) or not all_valid(depth):
                mask = valid_mask(depth, amplitude)
        filtered = self.filter(depth, mask)
        if not self.adaptive:
            return filtered
        f = self.fusion
        return _fuse(filtered, depth, amplitude, f.low, f.high, f.floor)
