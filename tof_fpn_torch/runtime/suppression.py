r"""The FPN suppression stage: broadband destriping, notch filtering, amplitude fusion, each optional.

Georgiev et al. (IEEE SAS 2015, Sec. III-IV) filter with a notch FIR and fuse the filtered and raw
depth by amplitude (eq. 11). :class:`FPNSuppression` composes, in this order:

1. ``filter`` (optional): the notch :class:`FPNFilter` (the periodic stripes);
2. ``fusion`` (optional): :class:`AmplitudeFusion` of the notch output with its input;
3. ``gate`` (default on): the notch part (1 + 2) is applied as ``y + g (notched - y)`` with the
   per-image :func:`~tof_fpn_torch.runtime.gate.stripe_gate` ``g``, which stays 0 unless the frame
   has stripes the notch removes, so a stripe-free frame comes out as it went in;
4. ``destripe`` (optional): a broadband column / row offset remover (beyond the paper) for what
   the notch leaves: offsets at all frequencies. It runs last, so the periodic stripes, whose
   strength follows the amplitude pixel by pixel, are the notch's, and the column-average
   estimate of the destriper sees only the broadband rest.

**How far a valid pixel moves.** Steps 1-3 change a valid pixel by ``g w (y - x)``: the filter's
change ``y - x`` times the fusion weight ``w`` (in [floor, 1]) and the gate ``g`` (in [0, 1]); so,
gate on or off, no valid pixel moves further than the filter lets it
(:mod:`~tof_fpn_torch.runtime.holes`): ``|y_n - x_n| <= sum_{k != c} |h_k| * max |x_m - x_n| +
|H(0) - 1| |x_n|``, the maximum over the *usable* depths ``x_m`` within the filter's support on the
filtered line, ``c`` the pixel's own tap. Usable means valid and not an isolated outlier (more than
3 times, or under a third of, each valid neighbour along the line): a 3.6 m return among 0.35 m
moves none of its neighbours. ``sum_{k != c} |h_k|`` is 1.13 for the default ``{20, 0.14}``
design, and ``H(0) = 1`` unless ``unit_dc=False``. Step 4 (``destripe``) then subtracts its column
/ row offsets.

Build one with :func:`tof_fpn_torch.build.suppression_from_design` (the paper's ``{20, 0.14}``,
unit DC gain) or :func:`tof_fpn_torch.build.suppression_from_data` (pieces picked from what is
detected); the paper's ungated stage is ``suppression_from_design(gate=False)``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .. import constants as K
from ._checks import check_image, check_same_shape
from .fpn_filter import FPNFilter, _tracing
from .fusion import AmplitudeFusion
from .gate import line_gate, noise_power, risk_shrinkage
from .stage import RecordField, Setting, Stage
from .trainable import TrainableFusion
from .validity import all_valid, valid_mask

__all__ = ["FPNSuppression"]


def _noise_gain(taps: torch.Tensor) -> float:
    """``||delta - h||^2``: the white-noise power gain of ``I - H`` (odd-length taps)."""
    d = taps.detach().double().clone()
    d[d.numel() // 2] -= 1.0
    return float((d * d).sum())


def _centre(taps: torch.Tensor, dims: int) -> float:
    """The tap that maps a pixel onto itself, to the power of the filtered dimensions (the largest
    tap for an even length: an upper bound, which keeps the gate's risk estimate cautious)."""
    t = taps.detach().double()
    c = float(t[t.numel() // 2]) if t.numel() % 2 else float(t.max())
    return c**dims


class FPNSuppression(Stage):
    r"""Fixed-pattern-noise suppression of ToF depth (see the module docstring).

    Args:
        filter: the notch :class:`FPNFilter`, or None.
        fusion: :class:`AmplitudeFusion` (eq. 11) of the notch output, or None (then no amplitude
            is needed).
        destripe: a broadband offset remover (a module ``(depth, amplitude) -> depth``), or None.
        gate: apply the notch part through the per-image stripe gate.
        min_stripe: the gate's floor: the smallest stripe amplitude, in units of the per-pixel
            noise, that opens it.
        stripe_scale: the factor the gate's risk check applies to the stripe power it reads off
            a frame's column profile (> 0; 1: as read). The profile averages the stripes down
            each column, so where their strength varies with the amplitude the read power is
            the square of a mean, below the mean square the notch removes (2.6x on a planar
            scene with stripes ``exp(-A / 40)``); a builder that measured the stripes against
            the amplitude on calibration frames sets it
            (:func:`tof_fpn_torch.build.suppression_from_data`).

    Shape:
        - depth: (B, 1, H, W) float; invalid pixels (NaN, +-inf, <= 0, or an amplitude that is NaN,
          inf or negative) are returned unchanged.
        - amplitude: (B, 1, H, W) float, or None when no piece uses it.
        - Output: (B, 1, H, W).

    Example:
        >>> notch = FPNFilter(torch.tensor([0.25, 0.5, 0.25]), notches=(math.pi,))
        >>> m = FPNSuppression(notch, AmplitudeFusion())
        >>> m(torch.rand(1, 1, 32, 48) + 1.0, torch.full((1, 1, 32, 48), 100.0)).shape
        torch.Size([1, 1, 32, 48])
    """

    settings = (
        Setting("gate", bool, True, "apply the notch through the per-frame stripe gate"),
        Setting(
            "min_stripe",
            float,
            K.GATE_MIN_STRIPE,
            "noise units of stripe that open the gate",
            low=0.0,
        ),
        Setting(
            "stripe_scale",
            float,
            1.0,
            "factor on the stripe power the gate reads",
            low=0.0,
            open_low=True,
        ),
    )
    record = (
        RecordField("gate", "the notch's share applied to the frame, in [0, 1] (NaN: no notch)"),
    )
    __jit_ignored_attributes__ = ["estimate", "settings", "record"]
    __jit_unused_properties__ = ["design"]

    def __init__(
        self,
        filter: FPNFilter | None = None,
        fusion: AmplitudeFusion | None = None,
        destripe: nn.Module | None = None,
        gate: bool = True,
        min_stripe: float = K.GATE_MIN_STRIPE,
        stripe_scale: float = 1.0,
    ) -> None:
        super().__init__()
        if filter is not None and not isinstance(filter, FPNFilter):
            raise ValueError(f"filter must be an FPNFilter or None, got {type(filter).__name__}")
        if fusion is not None and not isinstance(fusion, (AmplitudeFusion, TrainableFusion)):
            raise ValueError(
                "fusion must be an AmplitudeFusion, a TrainableFusion or None, got "
                f"{type(fusion).__name__}"
            )
        if fusion is not None and filter is None:
            raise ValueError("fusion blends the notch filter's output: it needs a filter")
        if destripe is not None and not isinstance(destripe, nn.Module):
            raise ValueError(f"destripe must be an nn.Module or None, got {type(destripe)}")
        if gate and filter is not None and not filter.notches:
            raise ValueError(
                "gate=True tests for stripes at the filter's notch frequencies, but the filter "
                "has none (FPNFilter(..., notches=...)); give them or pass gate=False"
            )
        if not (isinstance(min_stripe, (int, float)) and 0.0 <= min_stripe < math.inf):
            raise ValueError(f"min_stripe must be a finite number >= 0, got {min_stripe!r}")
        if not (isinstance(stripe_scale, (int, float)) and 0.0 < stripe_scale < math.inf):
            raise ValueError(f"stripe_scale must be a finite number > 0, got {stripe_scale!r}")
        self.filter = filter
        self.fusion = fusion
        self.destripe = destripe
        self.gate = bool(gate) and filter is not None
        self.min_stripe = float(min_stripe)
        self.stripe_scale = float(stripe_scale)
        self.noise_gain = 0.0 if filter is None else _noise_gain(filter.taps)
        self.centre = 1.0 if filter is None else _centre(filter.taps, len(filter.dims))
        self.estimate = None  # the stripe estimate, when a builder made this module from data

    @property
    def design(self):
        """The offline design of the notch filter (when a builder made this module), else None."""
        return None if self.filter is None else self.filter.design

    @property
    def needs_amplitude(self) -> bool:
        """Whether :meth:`forward` needs an amplitude: the notch output is fused with the raw
        depth by amplitude (eq. 11; the "adaptive" stage of the paper)."""
        return self.fusion is not None

    def extra_repr(self) -> str:
        return f"gate={self.gate}, min_stripe={self.min_stripe}, stripe_scale={self.stripe_scale}"

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        check_image(depth, "depth", 1)
        if amplitude is not None:
            check_image(amplitude, "amplitude", 1)
            check_same_shape(amplitude, depth, "amplitude", "depth")
        elif self.fusion is not None:
            raise ValueError(
                "amplitude is required: this stage fuses by amplitude (eq. 11); pass it, or "
                "build the stage with fusion=None"
            )
        mask: torch.Tensor | None = None
        if _tracing():
            mask = valid_mask(depth, amplitude)
        elif depth.numel() > 0:  # one min/max each instead of a mask when all are valid
            amp_ok = True
            if amplitude is not None:
                lo, hi = torch.aminmax(amplitude)
                amp_ok = bool(lo >= 0) and bool(hi < math.inf)
            if not amp_ok or not all_valid(depth):
                mask = valid_mask(depth, amplitude)
        record = torch.jit.annotate(dict[str, torch.Tensor], {})
        y = self._notch(depth, amplitude, mask, record)
        destripe = self.destripe
        if destripe is not None:
            y = destripe(y, amplitude)
        return y, record

    def _notch(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None,
        mask: torch.Tensor | None,
        record: dict[str, torch.Tensor],
    ) -> torch.Tensor:
        """Steps 1-3: the gated notch filter and fusion; puts the gate per frame in ``record``."""
        notch = self.filter
        B = depth.shape[0]
        if notch is None:  # no notch: no gate
            record["gate"] = torch.full((B,), math.nan, device=depth.device)
            return depth
        filtered = notch(depth, mask)
        out = filtered
        fusion = self.fusion
        if fusion is not None and amplitude is not None:
            out = fusion(filtered, depth, amplitude)
        if not self.gate:
            record["gate"] = torch.ones(B, device=depth.device)
            return out
        g = self._gate(depth, amplitude, mask, filtered, out)
        if g is None:  # no stripes anywhere: nothing to weigh
            record["gate"] = torch.zeros(B, device=depth.device)
            return depth
        record["gate"] = g.detach().flatten().float()
        blended = depth + g.to(depth.dtype) * (out - depth)
        if mask is None:
            return blended
        return torch.where(mask, blended, depth)

    def _gate(
        self,
        depth: torch.Tensor,
        amplitude: torch.Tensor | None,
        mask: torch.Tensor | None,
        filtered: torch.Tensor,
        out: torch.Tensor,
    ) -> torch.Tensor | None:
        """(B, 1, 1, 1) gate: the line test times the risk check (None in eager mode when the
        line test is closed for every image)."""
        notch = self.filter
        assert notch is not None
        fusion = self.fusion
        g, stripes = line_gate(
            depth, filtered, mask, notch.dims, notch.notches, self.noise_gain, self.min_stripe
        )
        if not _tracing() and not bool(g.any()):
            return None
        weight = torch.ones_like(depth)
        if fusion is not None and amplitude is not None:  # the fusion is affine in its inputs:
            weight = fusion(weight + 1.0, weight, amplitude) - 1.0  # its weight w_p, any kind
        noise = noise_power(depth, amplitude, mask)
        stripes = stripes * self.stripe_scale
        return g * risk_shrinkage(out - depth, weight, noise, stripes, self.centre, mask)
