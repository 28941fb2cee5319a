"""TorchScript and ONNX export of the run-time modules (:class:`FPNSuppression`, :class:`FPNFilter`).

TorchScript scripts the module as it is (its fast path; TorchScript keeps the branches) and keeps
the design attributes (``order``, ``rho``, ``notches``, ``dims``, ...). ONNX goes through
``torch.onnx.export(..., dynamo=True)`` with dynamic batch, height and width (a module whose class
sets ``onnx_dynamo = False`` goes through the TorchScript-based exporter instead, same dynamic
axes); while it traces, every
:class:`FPNFilter` sees :func:`torch.compiler.is_compiling` and takes its branch-free out-of-place
path (mathematically identical to the in-place one, checked in ``tests/test_export.py``). The
design attributes go into the ONNX model's ``metadata_props``. ONNX needs the ``onnx`` extra:
``pip install "tof_fpn_torch[onnx]"``.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import torch
from torch import nn

from . import constants as K
from .runtime import FPNFilter, freeze

__all__ = ["EXPORT_TOLERANCE", "MIN_OPSET", "export_onnx", "export_torchscript", "filter_metadata"]

MIN_OPSET = 17
#: largest |exported - eager| accepted when an export is checked (metres for depth models)
EXPORT_TOLERANCE = 1e-5
_ONNX_PACKAGES = ("onnx", "onnxscript")


def _check_module(module) -> None:
    if not isinstance(module, nn.Module):
        raise ValueError(f"module must be a torch.nn.Module, got {type(module).__name__}")


def filter_metadata(module: nn.Module) -> dict[str, str]:
    """``{key: JSON string}`` describing every :class:`FPNFilter` in ``module`` (design and
    geometry), e.g. ``{"filter.order": "20", "filter.rho": "0.14", ...}``."""
    out: dict[str, str] = {}
    for name, sub in module.named_modules():
        if isinstance(sub, FPNFilter):
            prefix = f"{name}." if name else ""
            values = {
                "order": sub.order,
                "rho": None if sub.rho != sub.rho else sub.rho,  # NaN = unknown
                "notches": sub.notches,
                "dims": sub.dims,
                "border": sub.border,
                "taps": sub.taps.detach().cpu().tolist(),
                "delay": sub.delay,
                "compensated": sub.compensated,
            }
            out.update({prefix + k: json.dumps(v) for k, v in values.items()})
    return out


def export_torchscript(module: nn.Module, path: str | Path | None = None) -> torch.jit.ScriptModule:
    """``torch.jit.script`` a copy of the module in eval mode and save it to ``path`` if given
    (parent directories are created). Trained parametrisations (e.g. notch taps that keep their
    zeros, :func:`~tof_fpn_torch.runtime.keep_zeros`) are frozen in the copy first."""
    _check_module(module)
    scripted = torch.jit.script(freeze(copy.deepcopy(module)).eval())
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        scripted.save(str(path))
    return scripted


def _require_onnx() -> None:
    import importlib.util

    missing = [p for p in _ONNX_PACKAGES if importlib.util.find_spec(p) is None]
    if missing:
        raise ModuleNotFoundError(
            f"ONNX export needs {', '.join(missing)}: install the onnx extra with "
            '`pip install "tof_fpn_torch[onnx]"` (or `pip install onnx onnxscript`)'
        )


def _check_onnx_exportable(module: nn.Module) -> None:
    """ValueError naming the reason when a submodule cannot be traced by ``torch.export``."""
    from .runtime import Destripe

    if any(isinstance(m, Destripe) for m in module.modules()):
        raise ValueError(
            "a Destripe module estimates its offsets from each frame with data-dependent robust "
            "statistics, which torch.export cannot trace: export it with TorchScript, or calibrate "
            "a fixed pattern (tof_fpn_torch.analysis.calibrate_fixed_pattern) and export its "
            "FixedPatternCorrection, which ONNX takes"
        )
    for m in module.modules():  # a module that cannot be traced says so (``onnx_unsupported``)
        reason = getattr(type(m), "onnx_unsupported", None)
        if reason:
            raise ValueError(f"cannot export {type(m).__name__} to ONNX: {reason}")


def _input_names(model: nn.Module) -> list[str]:
    """The graph's inputs: ``x`` of an :class:`FPNFilter`, the module's ``onnx_inputs`` where it
    names them (a stateful module: ``depth, state, amplitude``), else ``depth`` and, when the
    module needs one (``needs_amplitude``, True when it does not say), ``amplitude``."""
    if isinstance(model, FPNFilter):
        return ["x"]
    if getattr(model, "onnx_inputs", None):
        return list(model.onnx_inputs)
    if getattr(model, "needs_amplitude", True):
        return ["depth", "amplitude"]
    return ["depth"]


def _default_inputs(names: list[str], model: nn.Module) -> tuple[torch.Tensor, ...]:
    """(2, 1, 64, 80) float32 example inputs, seeded: depth in [0.5, 1.5), amplitude in
    [0.5, LOW_SENSING_THRESHOLD + 0.5); a ``state`` is the module's ``initial_state(depth)``."""
    gen = torch.Generator().manual_seed(0)
    out = [
        torch.rand(2, 1, 64, 80, generator=gen)
        * (K.LOW_SENSING_THRESHOLD if n == "amplitude" else 1.0)
        + 0.5
        for n in names
    ]
    if "state" in names:
        out[names.index("state")] = model.initial_state(out[0])
    return tuple(out)


def _exporter_options(model: nn.Module, names: list[str], dynamic: bool) -> dict:
    """``torch.onnx.export`` options: ``torch.export`` (dynamo) with dynamic batch, height and
    width, or the TorchScript-based exporter with the same dynamic axes where a submodule's class
    sets ``onnx_dynamo = False`` (a graph of many unrolled small loops, e.g.
    :class:`~tof_fpn_torch.runtime.FlyingPixels`: seconds instead of minutes, same graph values)."""
    if not all(getattr(type(m), "onnx_dynamo", True) for m in model.modules()):
        axes = {n: {0: "batch", 2: "height", 3: "width"} for n in names} if dynamic else None
        return dict(dynamo=False, dynamic_axes=axes)
    shapes = None
    if dynamic:
        b = torch.export.Dim("batch")
        h = torch.export.Dim("height", min=2)
        w = torch.export.Dim("width", min=2)
        shapes = {n: {0: b, 2: h, 3: w} for n in names}
    return dict(dynamo=True, dynamic_shapes=shapes, external_data=False)


def export_onnx(
    module: nn.Module,
    path: str | Path,
    example_inputs: tuple | None = None,
    opset: int = 18,
    dynamic: bool = True,
) -> Path:
    """Export to ONNX (opset >= 17) at ``path``, with the design in ``metadata_props``; a copy
    of the module is exported, its parametrisations frozen.

    Args:
        module: e.g. :class:`FPNSuppression` (inputs ``depth, amplitude``, or ``depth`` alone when
            its ``needs_amplitude`` is False), :class:`FPNFilter` (input ``x``) or a stateful
            :class:`~tof_fpn_torch.runtime.TemporalFilter` (inputs ``depth, state, amplitude``,
            outputs ``output, new_state``).
        example_inputs: tensors to trace with; default (2, 1, 64, 80) float32 (one per input).
        opset: ONNX opset, >= 17.
        dynamic: dynamic batch, height and width (each >= 2).

    Raises:
        ModuleNotFoundError: the ``onnx`` extra is not installed (the message says how).
    """
    _check_module(module)
    if isinstance(opset, bool) or not isinstance(opset, int) or opset < MIN_OPSET:
        raise ValueError(f"opset must be an int >= {MIN_OPSET}, got {opset!r}")
    _require_onnx()
    import onnx

    _check_onnx_exportable(module)
    model = freeze(copy.deepcopy(module)).eval()
    names = _input_names(model)
    if example_inputs is None:
        example_inputs = _default_inputs(names, model)
    if len(example_inputs) != len(names):
        raise ValueError(
            f"example_inputs must hold {len(names)} tensor(s) {names}, got {len(example_inputs)}"
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        model,
        tuple(example_inputs),
        str(path),
        input_names=names,
        output_names=list(getattr(model, "onnx_outputs", None) or ["output"]),
        opset_version=opset,
        **_exporter_options(model, names, dynamic),
    )
    proto = onnx.load(str(path))
    for key, value in filter_metadata(model).items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))
    return path
