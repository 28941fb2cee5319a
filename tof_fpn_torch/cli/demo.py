"""``tof-fpn demo``: synthetic scene -> FPN + noise -> FPN suppression -> NLM, one picture."""

from __future__ import annotations

import argparse
import inspect
import os

from ..demo import run_demo
from ._common import (
    MAX_SIZE,
    MIN_SIZE,
    check_output_dir,
    float_arg,
    int_arg,
    join,
    output_dirs,
    report_created,
    set_threads,
    threads_arg,
)

#: ``--out`` when not given.
DEFAULT_OUT = "demo_out"
#: The defaults of :func:`tof_fpn_torch.demo.run_demo` (the CLI's defaults).
_DEMO = {k: v.default for k, v in inspect.signature(run_demo).parameters.items()}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="end-to-end demo on a synthetic scene (seconds); writes demo.png",
        description="Synthetic low-sensing ToF scene -> eq. (10) FPN + eq. (2) noise -> FPN notch "
        "filter {order, rho} + adaptive fusion -> NLM. Writes demo.png (ground truth, input, "
        "NLM only, filtered, filtered + NLM, with PSNR) and demo.json; prints a summary.",
    )
    p.add_argument(
        "--out", default=DEFAULT_OUT, metavar="DIR", help="output directory (default %(default)s)"
    )
    p.add_argument(
        "--seed", type=int_arg(0), default=_DEMO["seed"], help="scene seed (default %(default)s)"
    )
    p.add_argument(
        "--size",
        type=int_arg(MIN_SIZE, MAX_SIZE),
        default=_DEMO["size"],
        help=f"scene side in pixels, {MIN_SIZE} to {MAX_SIZE} (default %(default)s)",
    )
    p.add_argument(
        "--order", type=int_arg(), default=_DEMO["order"], help="filter order (default %(default)s)"
    )
    p.add_argument(
        "--rho",
        type=float_arg(0.0, open_lo=True),
        default=_DEMO["rho"],
        help="transition half-width / pi (default %(default)s)",
    )
    p.add_argument(
        "--dpi",
        type=int_arg(),
        default=_DEMO["dpi"],
        help="resolution of demo.png (default %(default)s)",
    )
    p.add_argument(
        "--threads",
        type=threads_arg(),
        default=1,
        help="torch CPU threads, at most the CPU count (default %(default)s)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_output_dir("--out", args.out)
    set_threads(args.threads)
    with output_dirs(args.out) as created:
        res = run_demo(
            args.out, seed=args.seed, size=args.size, order=args.order, rho=args.rho, dpi=args.dpi
        )
    # the files run_demo wrote, under the directory as the user wrote it
    res.paths = {k: join(args.out, os.path.basename(v)) for k, v in res.paths.items()}
    report_created(created)
    print(res.summary())
    print(f"wrote {res.paths['png']}, {res.paths['json']}")
    return 0
