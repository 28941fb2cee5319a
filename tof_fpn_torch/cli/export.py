"""``tof-fpn export``: write an FPNSuppression stage as TorchScript or ONNX."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..constants import DEFAULT_NOTCHES
from .design import parse_frequency


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "export",
        help="export the FPN suppression stage (filter + amplitude fusion) to TorchScript or ONNX",
        description="Build FPNSuppression(order, rho, notches, dim, adaptive) and write it as a "
        "TorchScript archive or an ONNX model (inputs depth, amplitude: (B, 1, H, W) float32).",
    )
    p.add_argument("--format", choices=("torchscript", "onnx"), required=True)
    p.add_argument("--out", type=Path, required=True, help="output file (.pt or .onnx)")
    p.add_argument("--order", type=int, default=20, help="filter order N (default 20)")
    p.add_argument("--rho", type=float, default=0.14, help="transition parameter (default 0.14)")
    p.add_argument(
        "--notch",
        type=parse_frequency,
        action="append",
        metavar="W",
        help="notch frequency, e.g. 2pi/3 (repeat; default 2pi/3 and pi)",
    )
    p.add_argument(
        "--dim",
        choices=("columns", "rows", "both"),
        default="columns",
        help="stripes to remove: columns (filter along width, default), rows, both",
    )
    p.add_argument("--no-adaptive", action="store_true", help="skip the amplitude fusion (eq. 11)")
    p.add_argument("--opset", type=int, default=18, help="ONNX opset (>= 17, default 18)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..build import suppression_from_design
    from ..export import export_onnx, export_torchscript

    dim = {"columns": -1, "rows": -2, "both": (-2, -1)}[args.dim]
    module = suppression_from_design(
        args.order,
        args.rho,
        notches=tuple(args.notch) if args.notch else DEFAULT_NOTCHES,
        dim=dim,
        adaptive=not args.no_adaptive,
    )
    if args.format == "torchscript":
        export_torchscript(module, args.out)
    else:
        export_onnx(module, args.out, opset=args.opset)
    report = {
        "format": args.format,
        "out": str(args.out),
        "order": args.order,
        "rho": args.rho,
        "notches": list(module.design.notches),
        "dim": args.dim,
        "adaptive": module.adaptive,
        "taps": int(module.filter.taps.numel()),
        "delay": module.filter.delay,
        "ripple_db": module.design.ripple_db,
    }
    print(json.dumps(report, indent=2))
    return 0
