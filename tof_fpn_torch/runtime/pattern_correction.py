r"""A camera's fixed pattern as one stage: the corrections it is made of, applied in order
(torch only; TorchScript exportable).

A pattern learned from a camera's frames
(:func:`~tof_fpn_torch.analysis.learn_folder_pattern`) is offsets
(:class:`~tof_fpn_torch.runtime.FixedPatternCorrection`: column, row, pixel) and, where the
column pattern grows like ``1 / A``, a read-out offset of the complex signal
(:class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`); a calibrated pattern file may come
before them. :class:`PatternCorrection` applies them in order and carries, as text, what the
pattern was learned from.
"""

# no `from __future__ import annotations`: TorchScript reads the class-level attribute types below
import torch
from torch import nn

from .stage import Stage, empty_record

__all__ = ["PatternCorrection"]


class PatternCorrection(Stage):
    """Apply fixed-pattern corrections in order.

    Args:
        corrections: the stages, each ``(depth, amplitude) -> depth`` (e.g.
            :class:`~tof_fpn_torch.runtime.FixedPatternCorrection`,
            :class:`~tof_fpn_torch.runtime.ComplexPatternCorrection`); at least one.
        source: what the pattern is (e.g. ``"learned"``, ``"file"``, ``"file+learned"``).
        learned: what it was learned from, as JSON text (empty: not learned).

    Shape:
        - depth: (B, C, H, W) of the corrections' size; amplitude: the same (a read-out
          correction needs it).
        - Output: same shape and dtype; invalid pixels unchanged (each correction keeps them).
    """

    source: str
    learned: str

    def __init__(self, corrections: list, source: str = "learned", learned: str = "") -> None:
        super().__init__()
        if len(corrections) == 0:
            raise ValueError("corrections must hold at least one stage, got none")
        for c in corrections:
            if not isinstance(c, Stage):
                raise ValueError(f"each correction must be a Stage, got {type(c).__name__}")
        self.corrections = nn.ModuleList(corrections)
        self.source = str(source)
        self.learned = str(learned)

    def extra_repr(self) -> str:
        return f"source={self.source!r}"

    def _run(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        y = depth
        for c in self.corrections:
            y = c(y, amplitude)
        return y, empty_record()
