"""``tof-fpn design``: design an FPN notch filter, save its taps, print its figures of merit."""

from __future__ import annotations

import argparse
import json
import math
import os
import re
from fractions import Fraction

import numpy as np

from ..constants import DEFAULT_NOTCHES
from ..design import MAX_ORDER, design_fpn, fixed_zero_taps, max_rho
from ..design.bands import check_notches
from ._common import (
    UsageError,
    check_output_file,
    float_arg,
    int_arg,
    output_dirs,
    report_created,
)

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
    try:
        check_notches([value])
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"notch {text!r} = {value:g} rad/sample: a notch must lie in (0, pi]"
        ) from None
    return value


def format_frequency(w: float) -> str:
    """``2pi/3``, ``pi``, ``0.4pi``: ``w`` (radians) as a multiple of pi, as :func:`parse_frequency`
    reads it back."""
    frac = Fraction(w / math.pi).limit_denominator(12)
    if not math.isclose(float(frac) * math.pi, w, rel_tol=1e-12):
        return f"{w:.6g}"
    num = "" if frac.numerator == 1 else str(frac.numerator)
    return f"{num}pi" + ("" if frac.denominator == 1 else f"/{frac.denominator}")


def format_notches(notches) -> str:
    return ", ".join(format_frequency(float(w)) for w in notches)


def check_rho_fits(rho: float, notches) -> None:
    """``UsageError`` naming ``--rho`` when its transition bands would overlap around ``notches``
    (the bound is :func:`tof_fpn_torch.design.max_rho`); invalid notches raise its ValueError."""
    limit = max_rho(notches)
    if rho > limit * (1 + 1e-12):
        raise UsageError(
            f"--rho {rho:g} is too large for the notches {format_notches(sorted(notches))}: "
            f"rho must lie in (0, {limit:.6g}] (wider transition bands would overlap)"
        )


def min_order(notches=DEFAULT_NOTCHES) -> int:
    """Smallest order :func:`design_fpn` accepts for ``notches``: that of their fixed zeros."""
    return int(fixed_zero_taps(notches).size - 1)


def plot_suffixes() -> tuple[str, ...]:
    """The file name endings matplotlib can save a figure as (``.png``, ``.pdf``, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(f".{ext}" for ext in FigureCanvasBase.get_supported_filetypes()))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "design",
        help="design a linear-phase FPN notch filter (Remez with fixed zeros)",
        description="Design H(z) = A(z) G(z) with fixed zeros at the FPN frequencies and a minimax "
        "passband (Georgiev et al., IEEE SAS 2015, Sec. III), write its taps and report ripple, "
        "group delay and notch depths.",
    )
    p.add_argument(
        "--order",
        type=int_arg(),
        required=True,
        help=f"filter order N (N + 1 taps): from {min_order()} (the fixed zeros of the default "
        f"notches) to {MAX_ORDER}",
    )
    p.add_argument(
        "--rho",
        type=float_arg(0.0, open_lo=True),
        required=True,
        help="transition half-width / pi (eq. 8): in (0, "
        f"{max_rho(DEFAULT_NOTCHES):.6g}] for the default notches",
    )
    p.add_argument(
        "--notch",
        type=parse_frequency,
        action="append",
        metavar="W",
        help="notch frequency in rad/sample, e.g. 2pi/3 (repeat; default "
        f"{format_notches(DEFAULT_NOTCHES)})",
    )
    p.add_argument(
        "--band-weight",
        type=float_arg(0.0, open_lo=True),
        action="append",
        metavar="W",
        help="relative ripple weight of each passband (repeat once per band; default equal)",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="FILE.npy",
        help="output taps file, NumPy .npy (float64), written under exactly this name",
    )
    p.add_argument(
        "--plot",
        metavar="FILE",
        help="write the magnitude response (Fig. 6 style) here; the suffix sets the format "
        "(.png, .pdf, .svg, ...)",
    )
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_file("--out", args.out, (".npy",))
    if args.plot is not None:
        check_output_file("--plot", args.plot, plot_suffixes())
    notches = tuple(args.notch) if args.notch else DEFAULT_NOTCHES
    check_rho_fits(args.rho, notches)
    design = design_fpn(args.order, args.rho, notches=notches, band_weights=args.band_weight)
    with output_dirs(os.path.dirname(args.out), os.path.dirname(args.plot or "")) as created:
        with open(args.out, "wb") as fh:  # a file object: NumPy appends no ".npy"
            np.save(fh, design.taps)
        if args.plot is not None:
            from ..design.plot import plot_response

            plot_response(design, args.plot)
    report = design.summary()
    report["out"] = args.out
    if args.plot is not None:
        report["plot"] = args.plot
    if args.json:
        report["created"] = created
        print(json.dumps(report, indent=2))
        return 0
    report_created(created)
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
    if args.plot is not None:
        print(f"  response plot   : {args.plot}")
    return 0
