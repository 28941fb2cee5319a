"""``tof-fpn export``: write an FPNSuppression stage, or a trained whole model (``--model``), as
TorchScript or ONNX."""

from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import sys

from .. import constants as K
from .. import export as X
from ..cameras import PROFILES
from ._common import UsageError, check_output_file, float_arg, int_arg, output_dirs
from .design import check_rho_fits, format_notches, parse_frequency

#: ``--out`` when not given: this stem with the suffix of ``--format``.
DEFAULT_STEM = "fpn_suppression"
SUFFIXES: dict[str, str] = {"torchscript": ".pt", "onnx": ".onnx"}
#: ``--opset`` when not given: the default of :func:`tof_fpn_torch.export.export_onnx`.
DEFAULT_OPSET: int = inspect.signature(X.export_onnx).parameters["opset"].default
DIMS: dict[str, int | tuple[int, int]] = {"columns": -1, "rows": -2, "both": (-2, -1)}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="export the FPN suppression stage (filter + amplitude fusion) to TorchScript or ONNX",
        description="Build FPNSuppression(order, rho, notches, dim, adaptive) and write it as a "
        "TorchScript archive or an ONNX model (inputs depth, amplitude: (B, 1, H, W) float32); "
        "print a JSON report of the module written. ONNX needs the onnx extra: "
        'pip install "tof_fpn_torch[onnx]".',
    )
    p.add_argument(
        "--format",
        choices=tuple(SUFFIXES),
        required=True,
        help="torchscript (torch.jit archive) or onnx (needs the onnx extra)",
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        help="output file, written under exactly this name (default "
        + " or ".join(f"{DEFAULT_STEM}{s} for {f}" for f, s in SUFFIXES.items())
        + ")",
    )
    p.add_argument(
        "--model",
        metavar="CHECKPOINT",
        help="export this trained whole model (front end + network; a checkpoint written by "
        "examples/train_front_ends.py or tof_fpn_torch.learn.save_model) instead of building a "
        "stage; the outputs are checked against eager and the design options do not apply",
    )
    p.add_argument(
        "--order",
        type=int_arg(),
        default=K.DEFAULT_ORDER,
        help="filter order N (default %(default)s)",
    )
    p.add_argument(
        "--rho",
        type=float_arg(0.0, open_lo=True),
        default=K.DEFAULT_RHO,
        help="transition half-width / pi (default %(default)s)",
    )
    p.add_argument(
        "--notch",
        type=parse_frequency,
        action="append",
        metavar="W",
        help=f"notch frequency, e.g. 2pi/3 (repeat; default {format_notches(K.DEFAULT_NOTCHES)})",
    )
    p.add_argument(
        "--dim",
        choices=tuple(DIMS),
        default="columns",
        help="stripes to remove: columns (filter along width, default), rows, both",
    )
    p.add_argument("--no-adaptive", action="store_true", help="skip the amplitude fusion (eq. 11)")
    p.add_argument(
        "--camera",
        choices=sorted(PROFILES),
        default="camcube",
        help="camera profile whose amplitude units set the fusion thresholds (default camcube, "
        "the paper's 70 / 350)",
    )
    p.add_argument(
        "--no-gate",
        action="store_true",
        help="apply the notch to every frame (the paper's stage) instead of only to frames "
        "with stripes",
    )
    p.add_argument(
        "--opset",
        type=int_arg(),
        help=f"ONNX opset (--format onnx only; >= {X.MIN_OPSET}, default {DEFAULT_OPSET})",
    )
    p.set_defaults(func=run)


def _newest_opset() -> int:
    import onnx.defs

    return int(onnx.defs.onnx_opset_version())


def _written_opset(path: str) -> int:
    import onnx

    model = onnx.load(path, load_external_data=False)
    return next(o.version for o in model.opset_import if o.domain in ("", "ai.onnx"))


def run(args: argparse.Namespace) -> int:
    out = args.out if args.out is not None else DEFAULT_STEM + SUFFIXES[args.format]
    opset = args.opset
    if args.format == "onnx":
        try:
            X._require_onnx()
        except ModuleNotFoundError as exc:  # one line with the install hint
            raise UsageError(str(exc)) from None
        opset = DEFAULT_OPSET if opset is None else opset
        newest = _newest_opset()
        if opset > newest:
            raise UsageError(
                f"--opset must be an int in [{X.MIN_OPSET}, {newest}] ({newest}: the newest "
                f"opset the installed onnx knows), got {opset}"
            )
    elif opset is not None:
        raise UsageError(f"--opset {opset} applies to --format onnx only, not {args.format}")
    check_output_file("--out", out)
    if args.model is not None:
        return _run_model(args, out, opset)
    notches = tuple(args.notch) if args.notch else K.DEFAULT_NOTCHES
    check_rho_fits(args.rho, notches)

    from ..build import suppression_from_design

    module = suppression_from_design(
        args.order,
        args.rho,
        notches=notches,
        dim=DIMS[args.dim],
        adaptive=not args.no_adaptive,
        camera=args.camera,
        gate=not args.no_gate,
    )
    with output_dirs(os.path.dirname(out)) as created:
        if args.format == "torchscript":
            X.export_torchscript(module, out)
        else:
            with contextlib.redirect_stdout(sys.stderr):  # the exporter's progress lines
                X.export_onnx(module, out, opset=opset)
    f = module.filter
    report = {
        "format": args.format,
        "out": out,
        "order": f.order,
        "rho": f.rho,
        "notches": list(f.notches),
        "dims": list(f.dims),
        "adaptive": module.needs_amplitude,
        "fusion": None if module.fusion is None else [module.fusion.low, module.fusion.high],
        "gate": module.gate,
        "taps": int(f.taps.numel()),
        "delay": f.delay,
        "compensated": f.compensated,
        "ripple_db": module.design.ripple_db,
        "dc_gain": module.design.dc_gain,
    }
    if args.format == "onnx":
        report["opset"] = written = _written_opset(out)
        if written != opset:
            print(
                f"tof-fpn export: warning: asked for --opset {opset}, the exporter wrote opset "
                f"{written} (it could not convert the model)",
                file=sys.stderr,
            )
    report["created"] = created
    print(json.dumps(report, indent=2))
    return 0


#: the stage-building options, with their defaults: refused together with ``--model``
_DESIGN_OPTIONS: dict[str, object] = {
    "order": K.DEFAULT_ORDER,
    "rho": K.DEFAULT_RHO,
    "notch": None,
    "dim": "columns",
    "no_adaptive": False,
    "camera": "camcube",
    "no_gate": False,
}


def _run_model(args: argparse.Namespace, out: str, opset: int | None) -> int:
    given = [
        "--" + k.replace("_", "-") for k, v in _DESIGN_OPTIONS.items() if getattr(args, k) != v
    ]
    if given:
        raise UsageError(
            f"{', '.join(given)} build a stage and do not apply with --model (the checkpoint "
            "holds the trained front end)"
        )
    from ..learn import load_model

    try:
        model, info = load_model(args.model)
    except (FileNotFoundError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    import torch

    gen = torch.Generator().manual_seed(0)
    depth = 1.0 + 3.0 * torch.rand(2, 1, 48, 64, generator=gen)
    amp = 1.0 + 100.0 * torch.rand(2, 1, 48, 64, generator=gen)
    depth[0, 0, 5, 7] = float("nan")  # invalid pixels must come out invalid
    depth[1, 0, 9, 10:13] = 0.0
    with torch.no_grad():
        ref = model(depth, amp)
    with output_dirs(os.path.dirname(out)) as created:
        if args.format == "torchscript":
            got = X.export_torchscript(model, out)(depth, amp)
        else:
            with contextlib.redirect_stdout(sys.stderr):  # stdout holds the JSON report only
                X.export_onnx(model, out, example_inputs=(depth, amp), opset=opset)
            got = _run_onnx(out, depth, amp)
    diff = float((got - ref).nan_to_num().abs().max())
    invalid_kept = bool(torch.isnan(got[0, 0, 5, 7]) and (got[1, 0, 9, 10:13] == 0).all())
    report = {
        "format": args.format,
        "out": out,
        "model": args.model,
        "front": info["front"],
        "thresholds": list(info["thresholds"]),
        "max_abs_diff_vs_eager": diff,
        "invalid_kept": invalid_kept,
        "created": created,
    }
    print(json.dumps(report, indent=2))
    if diff > X.EXPORT_TOLERANCE or not invalid_kept:
        print(
            f"tof-fpn export: error: the exported model differs from eager by {diff:.3g} "
            f"(tolerance {X.EXPORT_TOLERANCE:g}) or lost invalid pixels",
            file=sys.stderr,
        )
        return 1
    return 0


def _run_onnx(path: str, depth, amp):
    import torch

    try:
        import onnxruntime as ort
    except ModuleNotFoundError:
        raise UsageError(
            'checking the ONNX model needs onnxruntime: pip install "tof_fpn_torch[onnx]"'
        ) from None
    sess = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    (out,) = sess.run(None, {"depth": depth.numpy(), "amplitude": amp.numpy()})
    return torch.from_numpy(out)
