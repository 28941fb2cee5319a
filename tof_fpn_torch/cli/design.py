"""``tof-fpn design``: design an FPN notch filter, save its taps, print its figures of merit."""

from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path

import numpy as np

from ..constants import DEFAULT_NOTCHES
from ..design import design_fpn, fixed_zero_taps

_FREQ = re.compile(r"^\s*([0-9.eE+-]*)\s*\*?\s*(pi)?\s*(?:/\s*([0-9.eE+-]+))?\s*$")


def parse_frequency(text: str) -> float:
    """Radians per sample from ``"2.0944"``, ``"pi"``, ``"2pi/3"``, ``"2*pi/3"`` or ``"0.5pi"``."""
    m = _FREQ.match(text.lower())
    if not m or not (m.group(1) or m.group(2)):
        raise argparse.ArgumentTypeError(
            f"notch {text!r} is not a frequency: use radians (2.0944) or a multiple of pi (2pi/3)"
        )
    try:
        value = float(m.group(1)) if m.group(1) not in (None, "", "+", "-") else 1.0
        if m.group(1) == "-":
            value = -1.0
        if m.group(2):
            value *= math.pi
        if m.group(3):
            value /= float(m.group(3))
    except (ValueError, ZeroDivisionError) as exc:
        raise argparse.ArgumentTypeError(f"notch {text!r} is not a frequency") from exc
    return value


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "design",
        help="design a linear-phase FPN notch filter (Remez with fixed zeros)",
        description="Design H(z) = A(z) G(z) with fixed zeros at the FPN frequencies and a minimax "
        "passband (Georgiev et al., IEEE SAS 2015, Sec. III), write its taps and report ripple, "
        "group delay and notch depths.",
    )
    p.add_argument("--order", type=int, required=True, help="filter order N (N + 1 taps)")
    p.add_argument("--rho", type=float, required=True, help="transition half-width / pi (eq. 8)")
    p.add_argument(
        "--notch",
        type=parse_frequency,
        action="append",
        metavar="W",
        help="notch frequency in rad/sample, e.g. 2pi/3 (repeat; default 2pi/3 and pi)",
    )
    p.add_argument(
        "--band-weight",
        type=float,
        action="append",
        metavar="W",
        help="relative ripple weight of each passband (repeat once per band; default equal)",
    )
    p.add_argument("--out", type=Path, required=True, help="output taps file (.npy, float64)")
    p.add_argument("--plot", type=Path, help="write the magnitude response (Fig. 6 style) here")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    design = design_fpn(
        args.order,
        args.rho,
        notches=tuple(args.notch) if args.notch else DEFAULT_NOTCHES,
        band_weights=args.band_weight,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.save(args.out, design.taps)
    if args.plot:
        from ..design.plot import plot_response

        plot_response(design, args.plot)
    report = design.summary()
    report["out"] = str(args.out)
    if args.plot:
        report["plot"] = str(args.plot)
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"FPN notch filter: order {design.order} ({design.taps.size} taps), rho {design.rho:g}")
    print(f"  passband ripple : delta = {design.ripple:.4e}  ({design.ripple_db:.2f} dB)")
    for k, ((lo, hi), r) in enumerate(zip(design.bands, design.band_ripples, strict=True)):
        print(f"    band {k}: [{lo / math.pi:.4f}, {hi / math.pi:.4f}] pi  ripple {r:.4e}")
    delay = "half-sample" if design.half_sample_delay else "integer"
    print(f"  group delay     : {design.group_delay:g} samples ({delay})")
    for w0, g, db in zip(design.notches, design.notch_gains, design.notch_depths_db, strict=True):
        print(f"  notch {w0 / math.pi:.4f} pi  : |H| = {g:.2e}  ({db:.1f} dB)")
    full = design.order - (fixed_zero_taps(design.notches).size - 1)
    if design.g_order < full:
        print(
            f"  note            : G optimised at order {design.g_order} < {full}: the full problem "
            "lies below float64 precision (ripple < RIPPLE_FLOOR)"
        )
    print(f"  taps written to : {args.out}")
    if args.plot:
        print(f"  response plot   : {args.plot}")
    return 0
