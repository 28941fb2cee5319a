r"""Correction of a calibrated fixed pattern (torch only; TorchScript and ONNX exportable).

A fixed pattern measured offline (:func:`tof_fpn_torch.analysis.calibrate_fixed_pattern`) is
removed from every frame as

    ``D' = (D - o(y, x)) / g(x)``,   ``o(y, x) = c(x) + r(y) + p(y, x)``

with per-column offsets ``c``, per-row offsets ``r``, per-pixel offsets ``p`` and per-column gains
``g`` (1 where none was calibrated), all held as float64 buffers. Invalid pixels
(:func:`~tof_fpn_torch.runtime.valid_mask`) are returned bit-identical, and where the correction
would make a valid depth invalid (``<= 0``) the input is kept. Unlike
:func:`~tof_fpn_torch.runtime.destripe` nothing is estimated at run time: the module is a few
element-wise operations, exported as they are.
"""

# no `from __future__ import annotations`: TorchScript reads the class-level attribute types below
import torch

from ._checks import check_image, check_same_shape
from .stage import Stage, empty_record
from .validity import valid_mask

__all__ = ["FixedPatternCorrection"]


def _vector(v, name: str, n: int | None) -> torch.Tensor:
    t = torch.as_tensor(v, dtype=torch.float64).detach().clone()
    if t.dim() != 1 or (n is not None and t.numel() != n):
        want = "a 1-D tensor" if n is None else f"a 1-D tensor of {n} values"
        raise ValueError(f"{name} must be {want}, got shape {list(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} must be finite, got {int((~torch.isfinite(t)).sum())} NaN/inf")
    return t


class FixedPatternCorrection(Stage):
    r"""Remove a calibrated fixed pattern: ``(D - c(x) - r(y) - p(y, x)) / g(x)``.

    Args:
        column_offset: (W,) per-column offsets ``c``, depth units.
        row_offset: optional (H,) per-row offsets ``r`` (needs ``pixel_offset`` or ``height``).
        pixel_offset: optional (H, W) per-pixel offsets ``p``.
        column_gain: optional (W,) per-column gains ``g`` (> 0).
        height: H when only column offsets are given (None: any height is accepted).

    Shape:
        - depth: (B, C, H, W) float with the calibrated W (and H when rows or pixels are
          calibrated); amplitude: optional, same shape (extends the validity rule).
        - Output: same shape, dtype and device; invalid pixels unchanged.

    Example:
        >>> m = FixedPatternCorrection(torch.tensor([0.0, 0.5, -0.5]))
        >>> m(torch.full((1, 1, 2, 3), 2.0))
        tensor([[[[2.0000, 1.5000, 2.5000],
                  [2.0000, 1.5000, 2.5000]]]])
    """

    height: int
    width: int

    def __init__(
        self,
        column_offset,
        row_offset=None,
        pixel_offset=None,
        column_gain=None,
        height: int | None = None,
    ) -> None:
        super().__init__()
        c = _vector(column_offset, "column_offset", None)
        w = c.numel()
        h = -1 if height is None else int(height)
        if pixel_offset is not None:
            p = torch.as_tensor(pixel_offset, dtype=torch.float64).detach().clone()
            if p.dim() != 2 or p.shape[1] != w or (h >= 0 and p.shape[0] != h):
                raise ValueError(
                    f"pixel_offset must have shape (H, {w}) (H = height), got {list(p.shape)}"
                )
            if not bool(torch.isfinite(p).all()):
                raise ValueError("pixel_offset must be finite")
            h = p.shape[0]
        if row_offset is not None:
            r = _vector(row_offset, "row_offset", None if h < 0 else h)
            h = r.numel()
        if h < 0 and (row_offset is not None or pixel_offset is not None):
            raise ValueError("the height is unknown")
        offset = c.view(1, w).clone()
        if row_offset is not None:
            offset = offset + r.view(-1, 1)
        if pixel_offset is not None:
            offset = offset + p
        g = torch.ones(w, dtype=torch.float64)
        if column_gain is not None:
            g = _vector(column_gain, "column_gain", w)
            if not bool((g > 0).all()):
                raise ValueError(f"column_gain must be > 0, got minimum {float(g.min())}")
        self.height = h
        self.width = w
        self.register_buffer("offset", offset)  # (1 or H, W)
        self.register_buffer("gain", g.view(1, w))

    def extra_repr(self) -> str:
        h = "any" if self.height < 0 else str(self.height)
        return f"height={h}, width={self.width}, offset_rows={self.offset.shape[0]}"

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        check_image(depth, "depth")
        if amplitude is not None:
            check_image(amplitude, "amplitude")
            check_same_shape(amplitude, depth, "amplitude", "depth")
        if depth.shape[-1] != self.width or (self.height >= 0 and depth.shape[-2] != self.height):
            h = "H" if self.height < 0 else str(self.height)
            raise ValueError(
                f"depth must have the calibrated size (..., {h}, {self.width}), got shape "
                f"{list(depth.shape)}"
            )
        off = self.offset.to(depth.dtype)
        gain = self.gain.to(depth.dtype)
        out = (depth - off) / gain
        # invalid pixels come out bit-identical; a valid pixel never comes out invalid
        return torch.where(
            valid_mask(depth, amplitude) & valid_mask(out), out, depth
        ), empty_record()
