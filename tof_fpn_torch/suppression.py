r"""FPN suppression stage: notch filtering plus amplitude-gated fusion (Georgiev et al., Sec. III-IV).

``FPNSuppression`` = :class:`~tof_fpn_torch.fpn_filter.FPNFilter` followed (``adaptive=True``) by
:class:`~tof_fpn_torch.fusion.AmplitudeFusion` (eq. 11). The paper's best adaptive result on its
synthetic data is ``{order 20, rho 0.14}`` (Table I), the defaults here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from ._checks import check_image, check_nonnegative, check_same_shape
from .design import DEFAULT_NOTCHES
from .fpn_filter import FPNFilter
from .fusion import AmplitudeFusion, amplitude_fusion
from .stripes import StripeEstimate, estimate_stripes

__all__ = ["FPNSuppression", "max_rho"]


def max_rho(notches: Sequence[float]) -> float:
    """Largest ``rho`` for which :func:`tof_fpn_torch.design.fpn_bands` accepts ``notches``
    (half the gap between neighbouring notches, the full gap to 0 and to pi, over pi)."""
    w = np.sort(np.asarray(notches, dtype=np.float64).reshape(-1))
    gaps = [w[0]] + list(np.diff(w) / 2)
    if w[-1] < np.pi:
        gaps.append(np.pi - w[-1])
    return float(min(gaps) / np.pi)


class FPNSuppression(nn.Module):
    r"""Fixed-pattern-noise suppression of ToF depth: notch FIR + amplitude fusion.

    Args:
        order: filter order ``N`` (taps ``N + 1``).
        rho: transition half-width parameter (eq. 8).
        notches: FPN frequencies, radians/sample (default ``(2pi/3, pi)``).
        dim: ``-1`` (column stripes), ``-2`` (row stripes) or ``(-2, -1)``.
        adaptive: fuse with the raw depth by amplitude (eq. 11); else return the filtered depth.
        low, high, floor: :class:`AmplitudeFusion` parameters.
        border, compensate_delay, zero_is_invalid, trainable: see :class:`FPNFilter`.

    Shape:
        - depth: (B, 1, H, W) float; NaN or 0 = invalid (stays invalid in the output).
        - amplitude: (B, 1, H, W) float, >= 0.
        - Output: (B, 1, H, W).

    Example:
        >>> m = FPNSuppression()
        >>> m(torch.rand(1, 1, 32, 48) + 1.0, torch.full((1, 1, 32, 48), 100.0)).shape
        torch.Size([1, 1, 32, 48])
    """

    __jit_ignored_attributes__ = ["estimate"]
    __jit_unused_properties__ = ["design"]

    def __init__(
        self,
        order: int = 20,
        rho: float = 0.14,
        notches: Sequence[float] = DEFAULT_NOTCHES,
        dim=-1,
        adaptive: bool = True,
        low: float = 70.0,
        high: float = 350.0,
        floor: float = 0.2,
        border: str = "reflect",
        compensate_delay: bool = False,
        zero_is_invalid: bool = True,
        trainable: bool = False,
    ) -> None:
        super().__init__()
        self.filter = FPNFilter.from_design(
            order,
            rho,
            notches=notches,
            dim=dim,
            border=border,
            compensate_delay=compensate_delay,
            zero_is_invalid=zero_is_invalid,
            trainable=trainable,
        )
        self.fusion = AmplitudeFusion(low, high, floor)
        self.adaptive = bool(adaptive)
        self.estimate = None  # the StripeEstimate when built by from_data

    @property
    def design(self):
        """The :class:`~tof_fpn_torch.design.FPNDesign` of the filter."""
        return self.filter.design

    @classmethod
    def from_data(
        cls,
        frames: torch.Tensor,
        amplitudes: torch.Tensor | None = None,
        order: int = 20,
        rho: float | None = None,
        min_confidence: float = 0.5,
        estimate_kwargs: dict | None = None,
        **kwargs,
    ) -> FPNSuppression:
        """Design notches for the stripes :func:`estimate_stripes` finds in ``frames``.

        Components with ``confidence >= min_confidence`` are kept; their frequencies become the
        notches (within 1e-3 rad of pi snapped to pi), the orientations found set ``dim`` (both
        orientations share one notch set). ``rho`` defaults to ``min(0.14, 0.9 * max_rho)``.
        The estimate is kept in :attr:`estimate`.

        Raises:
            ValueError: bad input, or no stripe found (the message lists the best candidates).
        """
        est: StripeEstimate = estimate_stripes(frames, amplitudes, **(estimate_kwargs or {}))
        comps = [c for c in est.components if c.confidence >= min_confidence]
        if not comps:
            raise ValueError(
                "no periodic stripes found with confidence >= "
                f"{min_confidence} (components: {list(est.components)}); nothing to notch"
            )
        freqs = sorted(
            {math.pi if abs(c.frequency - math.pi) < 1e-3 else c.frequency for c in comps}
        )
        merged: list[float] = []
        for f in freqs:  # one notch for peaks closer than 0.02 rad
            if merged and f - merged[-1] < 0.02:
                continue
            merged.append(f)
        dims = sorted({c.dim for c in comps})
        if rho is None:
            rho = min(0.14, 0.9 * max_rho(merged))
        kwargs.setdefault("dim", tuple(dims) if len(dims) > 1 else dims[0])
        module = cls(order=order, rho=rho, notches=tuple(merged), **kwargs)
        module.estimate = est
        return module

    def extra_repr(self) -> str:
        return f"adaptive={self.adaptive}"

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor) -> torch.Tensor:
        check_image(depth, "depth", 1)
        check_image(amplitude, "amplitude", 1)
        check_same_shape(amplitude, depth, "amplitude", "depth")
        check_nonnegative(amplitude, "amplitude")
        filtered = self.filter(depth)
        if not self.adaptive:
            return filtered
        f = self.fusion  # inputs are checked above; apply eq. 11 directly
        return amplitude_fusion(filtered, depth, amplitude, f.low, f.high, f.floor)
