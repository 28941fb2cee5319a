"""``tof-fpn calibrate INPUT PATTERN``: a camera's fixed pattern from recordings of flat walls,
saved for ``tof-fpn clean --pattern PATTERN`` (:mod:`tof_fpn_torch.clean.pattern`).

Exit status: 0; 2 for a bad argument, an INPUT without usable frames or an existing PATTERN.
"""

from __future__ import annotations

import argparse
import math

from ..clean import CleanConfig
from ..clean.pattern import DOMAINS, calibrate
from ._common import float_arg, int_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="measure a camera's fixed pattern from frames of flat walls (for clean --pattern)",
        description="Read every frame of INPUT (what tof-fpn clean takes: frame files, camera "
        "files, folders), estimate the fixed column / row (and pixel) pattern, and write it to "
        "PATTERN (.npz). Record a flat wall (better: several walls or distances) with the "
        "settings you will clean with; more frames give a finer pattern.",
    )
    p.add_argument("input", metavar="INPUT", help="frames of flat walls: a file or a folder")
    p.add_argument("pattern", metavar="PATTERN", help="the pattern file to write (.npz, new)")
    p.add_argument(
        "--domain",
        choices=DOMAINS,
        default="depth",
        help="depth: offsets of the depth (default); complex: read-out offsets of the complex "
        "signal, which enter the depth as 1 / amplitude (needs --modulation-frequency); scenes: "
        "the pattern frames of different scenes share, as clean learns it (no flat wall needed)",
    )
    p.add_argument("--flat-field", action="store_true", help="depth: per-pixel offsets too")
    p.add_argument("--rows", action="store_true", help="complex: row offsets too")
    p.add_argument(
        "--modulation-frequency",
        type=float_arg(0.0, open_lo=True),
        metavar="HZ",
        help="complex domain: the camera's modulation frequency in Hz (e.g. 20e6)",
    )
    p.add_argument("--depth-scale", type=float_arg(0.0, open_lo=True), help="metres per unit")
    p.add_argument("--height", type=int_arg(1), help="rows of raw .bin / .raw frames")
    p.add_argument("--width", type=int_arg(1), help="columns of raw .bin / .raw frames")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    config = CleanConfig(depth_scale=args.depth_scale, height=args.height, width=args.width)
    pattern = calibrate(
        args.input,
        args.pattern,
        config,
        domain=args.domain,
        rows=args.rows,
        flat_field=args.flat_field,
        modulation_frequency_hz=args.modulation_frequency,
    )
    if args.domain == "scenes":
        print(f"{pattern.summary()}; wrote {args.pattern}")
        print(f"apply it with: tof-fpn clean INPUT OUTPUT --pattern {args.pattern}")
        return 0
    h, w = pattern.shape
    if args.domain == "depth":
        col = 1e3 * float(pattern.column_offset.std())
        row = 1e3 * float(pattern.row_offset.std())
        extra = "" if pattern.pixel_offset is None else ", per-pixel offsets"
        what = f"column offsets {col:.3f} mm RMS, row offsets {row:.3f} mm RMS{extra}"
    else:
        mag = float(math.hypot(pattern.column_offset_re.std(), pattern.column_offset_im.std()))
        what = f"complex column offsets {mag:.3g} amplitude units RMS"
    print(f"calibrated {h} x {w} from {pattern.frames} frame(s): {what}; wrote {args.pattern}")
    print(f"apply it with: tof-fpn clean INPUT OUTPUT --pattern {args.pattern}")
    return 0
