"""TorchScript and ONNX export of the run-time modules (:class:`FPNSuppression`, :class:`FPNFilter`).

Export uses a copy of the module in *export mode*: every :class:`FPNFilter` takes its branch-free
path (invalid-pixel filling always on, out-of-place block-Toeplitz GEMM), which is mathematically
identical to the in-place inference path and is checked against it in ``tests/test_export.py``.
ONNX goes through ``torch.onnx.export(..., dynamo=True)`` with dynamic batch, height and width;
data-dependent input checks (negative amplitude) are skipped in the exported graph.
"""

from __future__ import annotations

import copy
from pathlib import Path

import torch
from torch import nn

from .fpn_filter import FPNFilter

__all__ = ["MIN_OPSET", "export_onnx", "export_torchscript", "for_export"]

MIN_OPSET = 17


def for_export(module: nn.Module) -> nn.Module:
    """Deep copy of ``module`` in eval mode with every :class:`FPNFilter` in export mode."""
    if not isinstance(module, nn.Module):
        raise ValueError(f"module must be a torch.nn.Module, got {type(module).__name__}")
    out = copy.deepcopy(module).eval()
    for sub in out.modules():
        if isinstance(sub, FPNFilter):
            sub.export_mode = True
    return out


def export_torchscript(module: nn.Module, path: str | Path | None = None) -> torch.jit.ScriptModule:
    """``torch.jit.script`` the module (its normal, fast path; TorchScript handles the branches)
    and save it to ``path`` if given."""
    if not isinstance(module, nn.Module):
        raise ValueError(f"module must be a torch.nn.Module, got {type(module).__name__}")
    scripted = torch.jit.script(copy.deepcopy(module).eval())
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        scripted.save(str(path))
    return scripted


def export_onnx(
    module: nn.Module,
    path: str | Path,
    example_inputs: tuple | None = None,
    opset: int = 18,
    dynamic: bool = True,
) -> Path:
    """Export to ONNX (opset >= 17) at ``path``.

    Args:
        module: e.g. :class:`FPNSuppression` (inputs ``depth, amplitude``) or :class:`FPNFilter`
            (input ``x``).
        example_inputs: tensors to trace with; default (2, 1, 64, 80) float32 (one per input).
        opset: ONNX opset, >= 17.
        dynamic: dynamic batch, height and width (each >= 2).
    """
    if isinstance(opset, bool) or not isinstance(opset, int) or opset < MIN_OPSET:
        raise ValueError(f"opset must be an int >= {MIN_OPSET}, got {opset!r}")
    model = for_export(module)
    names = ["x"] if isinstance(model, FPNFilter) else ["depth", "amplitude"]
    if example_inputs is None:
        gen = torch.Generator().manual_seed(0)
        example_inputs = tuple(
            torch.rand(2, 1, 64, 80, generator=gen) * (300.0 if n == "amplitude" else 1.0) + 0.5
            for n in names
        )
    if len(example_inputs) != len(names):
        raise ValueError(
            f"example_inputs must hold {len(names)} tensor(s) {names}, got {len(example_inputs)}"
        )
    dynamic_shapes = None
    if dynamic:
        b = torch.export.Dim("batch")
        h = torch.export.Dim("height", min=2)
        w = torch.export.Dim("width", min=2)
        dynamic_shapes = {n: {0: b, 2: h, 3: w} for n in names}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        model,
        tuple(example_inputs),
        str(path),
        input_names=names,
        output_names=["output"],
        opset_version=opset,
        dynamo=True,
        dynamic_shapes=dynamic_shapes,
        external_data=False,
    )
    return path
