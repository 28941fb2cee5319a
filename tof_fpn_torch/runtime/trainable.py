r"""Trainable pieces of the FPN stage: notch taps that keep their zeros, and a learnable fusion.

**Zeros that hold while training.** The notch filter is ``H(z) = A(z) G(z)`` (eq. 4 of Georgiev
et al., IEEE SAS 2015): ``A`` holds the fixed zeros at the FPN frequencies, ``G`` is free. Training
the taps of ``H`` directly moves the zeros away after the first step. :class:`KeepZeros` is a
``torch.nn.utils.parametrize`` parametrisation of :attr:`FPNFilter.taps`: the trained tensor is
``G`` (made symmetric, so the filter keeps its linear phase), and ``taps = A * G / (A * G)(1)``
(full convolution, scaled to unit DC gain so that training cannot scale the depth: a DC gain of
1.06 is a 6 % depth bias; measured after 12 unconstrained steps) is recomputed on every access; ``right_inverse`` takes the designed taps to the
least-squares ``G`` (exact for taps that contain ``A``, as every design does). Gradients reach ``G``
only, so ``H`` is zero at the notches to rounding whatever the optimiser does
(:func:`keep_zeros`; ``tests/test_learn.py`` checks it after training).

**A learnable fusion.** :class:`TrainableFusion` is eq. (11) with ``low``, ``high - low`` and
``floor`` as parameters (positive through ``exp``, the floor in ``(0, 1)`` through a sigmoid),
initialised from given thresholds; the same ramp as :class:`AmplitudeFusion`, differentiable in the
thresholds almost everywhere.

For export, freeze the parametrisation (:func:`freeze`): the taps become a plain tensor again and
the module scripts and exports like any other. ``torch.jit.script`` of a module that still holds
the parametrisation is refused with a message saying so (TorchScript cannot run parametrisations).
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F
from torch.nn.utils import parametrize

from ._checks import check_fusion_inputs
from .fpn_filter import FPNFilter
from .validity import valid_mask

__all__ = ["KeepZeros", "TrainableFusion", "freeze", "keep_zeros"]


def _convolve(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Full linear convolution of two 1-D tensors (``numpy.convolve``)."""
    pad = b.numel() - 1
    return F.conv1d(a.view(1, 1, -1), b.flip(0).view(1, 1, -1), padding=pad).view(-1)


class KeepZeros(nn.Module):
    """Parametrisation ``taps = A * sym(G) / H(1)`` with ``A`` fixed (the FPN zeros, float64):
    zeros held, linear phase, unit DC gain."""

    def __init__(self, fixed: torch.Tensor) -> None:
        super().__init__()
        fixed = torch.as_tensor(fixed, dtype=torch.float64).detach().clone()
        if fixed.dim() != 1 or fixed.numel() < 2 or not bool(torch.isfinite(fixed).all()):
            raise ValueError(f"fixed must be finite 1-D taps of A(z), got {fixed!r}")
        self.register_buffer("fixed", fixed)

    def forward(self, g: torch.Tensor) -> torch.Tensor:
        g = 0.5 * (g + g.flip(0))  # symmetric: linear phase
        taps = _convolve(g, self.fixed.to(g.dtype))
        return taps / taps.sum()  # unit DC: a flat depth passes unchanged (no scale bias)

    def __prepare_scriptable__(self) -> KeepZeros:
        """Refuse ``torch.jit.script`` with the way out: TorchScript cannot run parametrisations
        (the scripted module would fail on its first call with "Parametrization is not working
        with scripting"), so a module holding one is refused when it is scripted."""
        raise RuntimeError(
            "cannot script a module whose notch taps are trainable (a KeepZeros parametrisation: "
            "TorchScript cannot run torch.nn.utils.parametrize). Call "
            "tof_fpn_torch.runtime.freeze(module) first (it leaves the current taps as plain "
            "parameters), or export with tof_fpn_torch.export.export_torchscript, which scripts "
            "a frozen copy"
        )

    def right_inverse(self, taps: torch.Tensor) -> torch.Tensor:
        """The least-squares ``G`` with ``A * G = taps``."""
        n = taps.numel() - self.fixed.numel() + 1
        if n < 1:
            raise ValueError(
                f"taps of length {taps.numel()} cannot contain A(z) of length {self.fixed.numel()}"
            )
        eye = torch.eye(n, dtype=torch.float64, device=taps.device)
        cols = torch.stack([_convolve(eye[i], self.fixed.to(taps.device)) for i in range(n)], 1)
        g = torch.linalg.lstsq(cols, taps.detach().double().view(-1, 1)).solution.view(-1)
        return g.to(taps.dtype)


def keep_zeros(module: FPNFilter, fixed) -> FPNFilter:
    """Make ``module.taps`` trainable through ``G`` with the zeros of ``A(z)`` (``fixed``, e.g.
    :func:`tof_fpn_torch.design.fixed_zero_taps`) held: a :class:`KeepZeros` parametrisation.
    The taps must already be a parameter (``FPNFilter(..., trainable=True)``)."""
    if not isinstance(module.taps, nn.Parameter):
        raise ValueError("keep_zeros needs FPNFilter(..., trainable=True): its taps are a buffer")
    parametrize.register_parametrization(module, "taps", KeepZeros(fixed), unsafe=True)
    return module


def freeze(module: nn.Module) -> nn.Module:
    """Remove every parametrisation in ``module``, leaving the current taps as plain parameters
    (for TorchScript / ONNX export). In place; returns ``module``."""
    for sub in list(module.modules()):
        if parametrize.is_parametrized(sub):
            # a deep copy of a parametrised module shares its generated class, and removing the
            # parametrisation deletes the property from that class: the original would lose its
            # taps. A private copy of the class keeps the two apart.
            cls = type(sub)
            sub.__class__ = type(cls.__name__, cls.__bases__, dict(cls.__dict__))
            for name in list(sub.parametrizations.keys()):
                parametrize.remove_parametrizations(sub, name, leave_parametrized=True)
    return module


class TrainableFusion(nn.Module):
    r"""Eq. (11) with learnable thresholds: ``D + delta_A (D_F - D)``, ``delta_A`` 1 up to
    ``low``, linear to ``floor`` at ``high``, ``floor`` above.

    Args:
        low, high, floor: initial values (``0 < low < high``, ``0 < floor < 1``).

    Shape:
        - filtered, depth, amplitude: (B, 1, H, W); invalid pixels keep ``depth``.
    """

    def __init__(self, low: float, high: float, floor: float) -> None:
        super().__init__()
        if not (0 < low < high < math.inf) or not (0 < floor < 1):
            raise ValueError(
                f"need 0 < low < high and 0 < floor < 1, got low={low}, high={high}, floor={floor}"
            )
        self.log_low = nn.Parameter(torch.tensor(math.log(low)))
        self.log_span = nn.Parameter(torch.tensor(math.log(high - low)))
        self.logit_floor = nn.Parameter(torch.tensor(math.log(floor / (1 - floor))))

    @property
    def low(self) -> float:
        return float(self.log_low.detach().exp())

    @property
    def high(self) -> float:
        return float(self.log_low.detach().exp() + self.log_span.detach().exp())

    @property
    def floor(self) -> float:
        return float(torch.sigmoid(self.logit_floor.detach()))

    def forward(
        self, filtered: torch.Tensor, depth: torch.Tensor, amplitude: torch.Tensor
    ) -> torch.Tensor:
        check_fusion_inputs(filtered, depth, amplitude)
        low = self.log_low.exp()
        span = self.log_span.exp()
        floor = torch.sigmoid(self.logit_floor)
        valid = valid_mask(depth, amplitude)
        # invalid pixels (NaN, inf) out of the arithmetic, not only out of the result: a NaN in
        # the branch torch.where drops still turns the thresholds' gradients into NaN
        zero = torch.zeros_like(depth)
        d = torch.where(valid, depth, zero)
        f = torch.where(valid, filtered, zero)
        a = torch.where(valid, amplitude, zero)
        delta = torch.clamp(1.0 - (1.0 - floor) * (a - low) / span, max=1.0)
        delta = torch.maximum(delta, floor).to(depth.dtype)
        return torch.where(valid, d + delta * (f - d), depth)
