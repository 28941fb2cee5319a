"""``tof-fpn export``: write an FPNSuppression stage as TorchScript or ONNX."""

from __future__ import annotations

import argparse
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
            X.export_onnx(module, out, opset=opset)
    f = module.filter
    report = {
        "format": args.format,
        "out": out,
        "order": f.order,
        "rho": f.rho,
        "notches": list(f.notches),
        "dims": list(f.dims),
        "adaptive": module.adaptive,
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
