"""The base of the run-time stages ``(depth, amplitude) -> depth``: float32 under autocast."""

from __future__ import annotations

import torch
from torch import nn

from ._checks import check_tensor_type

__all__ = ["Float32Stage"]


class Float32Stage(nn.Module):
    """A stage whose :meth:`forward` runs the subclass's ``_forward`` with autocast off.

    Depth in metres needs float32: bfloat16 keeps 8 significant bits (about 8 mm at 2 m), float16
    11. Under ``torch.autocast`` (a network trained in mixed precision behind the stage) the stage
    computes in float32 and returns its input's dtype; the layers behind it are cast by autocast
    as usual. TorchScript compiles ``_forward`` alone (a scripted module under autocast is JIT
    autocast's business).
    """

    def forward(self, depth: torch.Tensor, amplitude: torch.Tensor | None = None) -> torch.Tensor:
        if not torch.jit.is_scripting():
            check_tensor_type(depth, "depth")
            check_tensor_type(amplitude, "amplitude", optional=True)
            if torch.is_autocast_enabled(depth.device.type):
                return self._full_precision(depth, amplitude)
        return self._forward(depth, amplitude)

    @torch.jit.unused
    def _full_precision(
        self, depth: torch.Tensor, amplitude: torch.Tensor | None = None
    ) -> torch.Tensor:
        with torch.autocast(depth.device.type, enabled=False):
            return self._forward(depth, amplitude)

    def _forward(self, depth: torch.Tensor, amplitude: torch.Tensor | None = None) -> torch.Tensor:
        raise NotImplementedError("a Float32Stage subclass defines _forward(depth, amplitude)")
