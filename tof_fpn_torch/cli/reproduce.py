"""``tof-fpn reproduce table1|fig9``: the paper's synthetic experiment (Table I, Fig. 9).

Thin wrapper over :mod:`tof_fpn_torch.experiments`; see docs/experiments.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import experiments as E

#: ``--quick``: one small scene and (fig9) a coarse grid.
QUICK_SIZE = 128
QUICK_SEEDS = (0,)


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--seeds must be comma-separated ints >= 0, got {text!r}"
        ) from None
    if not seeds or min(seeds) < 0:
        raise argparse.ArgumentTypeError(f"--seeds must be comma-separated ints >= 0, got {text!r}")
    return seeds


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reproduce",
        help="reproduce the paper's synthetic experiment (Table I, Fig. 9)",
        description="Synthetic scene -> eq. (10) FPN (+ eq. (2) noise at 21.26 dB) -> FPN notch "
        "filter (+ eq. (11) fusion) -> NLM -> PSNR; writes CSV, JSON, Markdown (ours beside the "
        "paper) and PNG into --out.",
    )
    p.add_argument("experiment", choices=("table1", "fig9"), help="which result to reproduce")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"one {QUICK_SIZE}x{QUICK_SIZE} scene (fig9: coarse grid); seconds",
    )
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument("--seeds", type=_seeds, help="scene seeds, e.g. 0,1,2 (default 0,1,2; quick: 0)")
    p.add_argument("--size", type=int, help="scene side in pixels (default 204; quick: 96)")
    p.add_argument("--h", type=float, default=E.NLMSettings.h, help="NLM h relative to sigma")
    p.add_argument("--patch-size", type=int, default=E.NLMSettings.patch_size)
    p.add_argument("--patch-distance", type=int, default=E.NLMSettings.patch_distance)
    p.add_argument("--case", choices=E.CASES, default="fpn+noise", help="fig9 input case")
    p.add_argument(
        "--compensate-delay",
        action="store_true",
        help="table1: compensate the half-sample delay of odd orders",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1: the images are small, and 1 thread does not "
        "stall when another job holds the other core)",
    )
    p.set_defaults(func=run)


def set_threads(n: int) -> None:
    """``torch.set_num_threads(n)`` after checking ``n >= 1``."""
    import torch

    if n < 1:
        raise ValueError(f"--threads must be >= 1, got {n}")
    torch.set_num_threads(n)


def run(args: argparse.Namespace) -> int:
    set_threads(args.threads)
    seeds = args.seeds or (QUICK_SEEDS if args.quick else (0, 1, 2))
    size = args.size or (QUICK_SIZE if args.quick else 204)
    nlm = E.NLMSettings(args.patch_size, args.patch_distance, args.h).validate()
    progress = not args.no_progress
    if args.experiment == "table1":
        result = E.run_table1(
            seeds,
            size,
            nlm=nlm,
            compensate_delay=args.compensate_delay,
            progress=progress,
        )
        paths = E.write_table1(result, args.out)
        for c in E.CASES:
            rows = [r for r in result["rows"] if r["case"] == c]
            best = max(rows, key=lambda r: r["nlm_adaptive"])
            print(
                f"{E.CASE_LABELS[c]:12s}: input {result['input_psnr'][c]:.2f} dB, NLM not "
                f"filtered {rows[0]['nlm_unfiltered']:.2f} dB, best {{{best['order']}, "
                f"{best['rho']:g}}}: filtered {best['nlm_filtered']:.2f} dB "
                f"({best['gain_filtered']:+.2f}), + adaptive {best['nlm_adaptive']:.2f} dB "
                f"({best['gain_adaptive']:+.2f})"
            )
    else:
        kw = {}
        if args.quick:
            kw = {
                "odd_orders": E.QUICK_ODD_ORDERS,
                "even_orders": E.QUICK_EVEN_ORDERS,
                "rhos": E.QUICK_RHOS,
            }
        result = E.run_fig9(seeds, size, nlm=nlm, case=args.case, progress=progress, **kw)
        paths = E.write_fig9(result, args.out)
        print(
            f"{E.CASE_LABELS[result['case']]}: input {result['input_psnr']:.2f} dB, NLM not "
            f"filtered {result['nlm_unfiltered']:.2f} dB"
        )
        for name, b in result["best"].items():
            print(f"  best {name:18s}: {{{b['order']}, {b['rho']:g}}} {b['psnr']:.2f} dB")
    print(f"wrote {', '.join(str(p) for p in paths.values())} ({result['seconds']:.1f} s)")
    return 0
