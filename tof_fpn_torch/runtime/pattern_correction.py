r"""A camera's fixed pattern as one stage: the corrections it is made of, applied in order
(torch only; TorchScript exportable).

A pattern learned from a camera's frames
(:func:`~tof_fpn_torch.analysis.learn_folder_pattern`) is offsets
(:class:`~tof_fpn_torch.runtime.FixedPatternCorrection`: column, row, pixel) and, where the
column pattern grows like ``1 / A``, a read-out offset of the complex signal
(:class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`); a calibrated pattern file may come
before them. :class:`PatternCorrection` applies them in order and carries, as text, what the
pattern was learned from.

**Confirmed per frame** (``confirm=True``): a fixed pattern is rough, a scene is smooth, so a
correction that removes the frame's pattern lowers the mean absolute second difference of its
depth, along the rows and down the columns, over the valid pixels (edges and kinks count the same
before and after: an L1 measure is not dominated by them); a frame whose measure the correction
does not lower by :data:`CONFIRM_MARGIN` is returned as it was, and the record says so
(``applied``).
"""

# no `from __future__ import annotations`: TorchScript reads the class-level attribute types below
import torch
from torch import nn

from .stage import RecordField, Stage
from .validity import valid_mask

__all__ = ["CONFIRM_MARGIN", "PatternCorrection"]

#: a frame is corrected when the correction lowers its roughness by at least this share (the
#: frames a pattern was learned on lend it some of their own noise: a marginal drop is no proof)
CONFIRM_MARGIN = 0.02


class PatternCorrection(Stage):
    """Apply fixed-pattern corrections in order.

    Args:
        corrections: the stages, each ``(depth, amplitude) -> depth`` (e.g.
            :class:`~tof_fpn_torch.runtime.FixedPatternCorrection`,
            :class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`); at least one.
        source: what the pattern is (e.g. ``"learned"``, ``"file"``, ``"file+learned"``).
        learned: what it was learned from, as JSON text (empty: not learned).
        confirm: apply it only to the frames whose roughness it lowers (module docstring).

    Shape:
        - depth: (B, C, H, W) of the corrections' size; amplitude: the same (a read-out
          correction needs it).
        - Output: same shape and dtype; invalid pixels unchanged (each correction keeps them).
    """

    record = (
        RecordField("applied", "1: the correction lowered the frame's roughness and was applied"),
        RecordField("roughness_change", "relative change of the mean |second difference|"),
    )
    source: str
    learned: str
    confirm: bool
    margin: float

    def __init__(
        self, corrections: list, source: str = "learned", learned: str = "", confirm: bool = True
    ) -> None:
        super().__init__()
        if len(corrections) == 0:
            raise ValueError("corrections must hold at least one stage, got none")
        for c in corrections:
            if not isinstance(c, Stage):
                raise ValueError(f"each correction must be a Stage, got {type(c).__name__}")
        self.corrections = nn.ModuleList(corrections)
        self.source = str(source)
        self.learned = str(learned)
        self.confirm = bool(confirm)
        self.margin = CONFIRM_MARGIN

    def extra_repr(self) -> str:
        return f"source={self.source!r}, confirm={self.confirm}"

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        y = depth
        for c in self.corrections:
            y = c(y, amplitude)
        b = depth.shape[0]
        before = _roughness(depth, amplitude)
        after = _roughness(y, amplitude)
        change = torch.where(before > 0, after / before.clamp_min(1e-30) - 1.0, 0.0)
        if self.confirm:
            smoother = after < (1.0 - self.margin) * before
            y = torch.where(smoother.view(b, 1, 1, 1), y, depth)
            applied = smoother.to(depth.dtype)
        else:
            applied = torch.ones(b, dtype=depth.dtype, device=depth.device)
        return y, {"applied": applied, "roughness_change": change.to(depth.dtype)}


def _roughness(depth: torch.Tensor, amplitude: torch.Tensor | None) -> torch.Tensor:
    """(B,) mean absolute second difference along the rows and down the columns over the valid
    triples of each frame (all channels), float64."""
    x = depth.double()
    v = valid_mask(depth, amplitude)
    x = torch.where(v, x, torch.zeros_like(x))
    total = torch.zeros(x.shape[0], dtype=torch.float64, device=x.device)
    count = torch.zeros_like(total)
    if x.shape[-1] >= 3:
        e = x[..., :-2] - 2 * x[..., 1:-1] + x[..., 2:]
        ok = v[..., :-2] & v[..., 1:-1] & v[..., 2:]
        total += torch.where(ok, e.abs(), torch.zeros_like(e)).flatten(1).sum(1)
        count += ok.flatten(1).sum(1).double()
    if x.shape[-2] >= 3:
        e = x[..., :-2, :] - 2 * x[..., 1:-1, :] + x[..., 2:, :]
        ok = v[..., :-2, :] & v[..., 1:-1, :] & v[..., 2:, :]
        total += torch.where(ok, e.abs(), torch.zeros_like(e)).flatten(1).sum(1)
        count += ok.flatten(1).sum(1).double()
    return total / count.clamp_min(1.0)
