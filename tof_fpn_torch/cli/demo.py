"""``tof-fpn demo``: synthetic scene -> FPN + noise -> FPN suppression -> NLM, one picture."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..experiments import run_demo
from .reproduce import set_threads


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="end-to-end demo on a synthetic scene (seconds); writes demo.png",
        description="Synthetic low-sensing ToF scene -> eq. (10) FPN + eq. (2) noise -> FPN notch "
        "filter {order, rho} + adaptive fusion -> NLM. Writes demo.png (ground truth, input, "
        "NLM only, filtered, filtered + NLM, with PSNR) and demo.json; prints a summary.",
    )
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="output directory")
    p.add_argument("--seed", type=int, default=0, help="scene seed (>= 0)")
    p.add_argument("--size", type=int, default=204, help="scene side in pixels (>= 32)")
    p.add_argument("--order", type=int, default=28, help="filter order (default 28)")
    p.add_argument("--rho", type=float, default=0.13, help="transition width parameter (0.13)")
    p.add_argument("--dpi", type=int, default=60, help="resolution of demo.png (default 60)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    set_threads(args.threads)
    res = run_demo(
        args.out, seed=args.seed, size=args.size, order=args.order, rho=args.rho, dpi=args.dpi
    )
    print(res.summary())
    return 0
