"""Reproduce the paper: ``python benchmarks/reproduce.py table1|fig9|table2``: the synthetic
experiment (Table I, Fig. 9) and the denoiser comparison on simulated low-sensing captures
(Table II, Fig. 10), written as CSV, JSON, Markdown and PNG into ``--out``.

A thin command line over :mod:`paper` (``benchmarks/paper/``: the experiments) and
:mod:`tof_fpn_torch.paper_data` (the paper's synthetic data, shared with ``tof-fpn demo``). Every
error is one line on stderr with exit status 2.
"""

from __future__ import annotations

import argparse
import inspect
import sys

import paper as E

from tof_fpn_torch import constants as K
from tof_fpn_torch import denoise
from tof_fpn_torch.cli._common import (
    MAX_SIZE,
    MIN_H,
    MIN_SIZE,
    UsageError,
    check_output_dir,
    float_arg,
    int_arg,
    join,
    output_dirs,
    report_created,
    set_threads,
    threads_arg,
)

#: ``--quick``: one small scene and (fig9) a coarse grid.
QUICK_SIZE = 128
QUICK_SEEDS = (0,)
#: ``--out`` when not given.
DEFAULT_OUT = "reproduce_out"

#: ``table2 --quick``: a small capture (side, test frames per integration time, ground-truth frames).
QUICK_TABLE2 = {"size": 96, "frames": 1, "gt_frames": 50}

#: The defaults of the experiments (what runs without ``--seeds`` / ``--size`` / ``--case``).
_TABLE1 = inspect.signature(E.run_table1).parameters
_FIG9 = inspect.signature(E.run_fig9).parameters
#: Options that only one experiment reads (refused for the other).
_ONLY = {
    "case": "fig9",
    "compensate_delay": "table1",
    "frames": "table2",
    "gt_frames": "table2",
    "denoisers": "table2",
    "noise": "table2",
}
#: Options of Table I / Fig. 9 that Table II does not read (refused when given).
_NOT_TABLE2 = ("seeds", "h", "patch_size", "patch_distance", "case", "compensate_delay")


def _seeds(text: str) -> tuple[int, ...]:
    try:
        seeds = tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        seeds = ()
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(
            f"must be distinct comma-separated ints >= 0, e.g. 0,1,2, got {text!r}"
        )
    return seeds


def _denoisers(text: str) -> tuple[str, ...]:
    """Comma-separated registry names (aliases allowed) or ``all``."""
    if text.strip().lower() == "all":
        return tuple(denoise.names())
    try:
        names = tuple(denoise.canonical(s) for s in text.split(",") if s.strip())
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not names or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"must be distinct denoiser names, got {text!r}")
    return names


def _default(name: str) -> str:
    """The default of ``name`` in both experiments, as help text."""
    a, b = _TABLE1[name].default, _FIG9[name].default
    fmt = (lambda v: ",".join(map(str, v))) if name == "seeds" else str
    return fmt(a) if a == b else f"table1 {fmt(a)}, fig9 {fmt(b)}"


class _Parser(argparse.ArgumentParser):
    """Errors as one line (``prog: error: ...``) and exit status 2, like ``tof-fpn``."""

    def error(self, message: str):
        print(f"{self.prog}: error: {message}", file=sys.stderr)
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python benchmarks/reproduce.py",
        description="Synthetic scene -> eq. (10) FPN (+ eq. (2) noise at "
        f"{K.PAPER_INPUT_PSNR['fpn+noise']:g} dB) -> FPN notch "
        "filter (+ eq. (11) fusion) -> NLM -> PSNR; writes CSV, JSON, Markdown (ours beside the "
        "paper) and PNG into --out. table2: the raw-level simulator's low-sensing captures (50, "
        "100, 200 us) with and without FPN suppression, each denoiser's PSNR beside Table II.",
    )
    p.add_argument(
        "experiment", choices=("table1", "fig9", "table2"), help="which result to reproduce"
    )
    quick_seeds = ",".join(map(str, QUICK_SEEDS))
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"seed(s) {quick_seeds} at {QUICK_SIZE}x{QUICK_SIZE} (fig9: odd orders "
        f"{', '.join(map(str, E.QUICK_ODD_ORDERS))}, even orders "
        f"{', '.join(map(str, E.QUICK_EVEN_ORDERS))}, rho "
        f"{', '.join(f'{r:g}' for r in E.QUICK_RHOS)}); table2: {QUICK_TABLE2['size']}x"
        f"{QUICK_TABLE2['size']}, {QUICK_TABLE2['frames']} frame, ground truth of "
        f"{QUICK_TABLE2['gt_frames']} frames; seconds",
    )
    p.add_argument(
        "--out", default=DEFAULT_OUT, metavar="DIR", help="output directory (default %(default)s)"
    )
    p.add_argument(
        "--seeds",
        type=_seeds,
        help=f"scene seeds, e.g. 0,1,2 (default {_default('seeds')}; --quick: {quick_seeds})",
    )
    p.add_argument(
        "--size",
        type=int_arg(MIN_SIZE, MAX_SIZE),
        help=f"scene side in pixels, {MIN_SIZE} to {MAX_SIZE} (default {_default('size')}; "
        f"--quick: {QUICK_SIZE})",
    )
    nlm = E.NLMSettings()
    p.add_argument(
        "--h",
        type=float_arg(MIN_H),
        default=nlm.h,
        help="NLM h relative to sigma (default %(default)s)",
    )
    p.add_argument(
        "--patch-size",
        type=int_arg(1),
        default=nlm.patch_size,
        help="NLM patch side, odd, at most --size (default %(default)s)",
    )
    p.add_argument(
        "--patch-distance",
        type=int_arg(0),
        default=nlm.patch_distance,
        help="NLM search radius, below --size (default %(default)s)",
    )
    p.add_argument(
        "--case",
        choices=E.CASES,
        help=f"fig9 only: input case (default {_FIG9['case'].default})",
    )
    p.add_argument(
        "--compensate-delay",
        action="store_true",
        help="table1 only: compensate the half-sample delay of odd orders",
    )
    p.add_argument(
        "--frames",
        type=int_arg(1),
        help=f"table2 only: test frames per integration time (default {E.Table2Setup().frames})",
    )
    p.add_argument(
        "--gt-frames",
        type=int_arg(1),
        help="table2 only: frames averaged at 2000 us for the ground truth (default "
        f"{E.Table2Setup().gt_frames}, the paper's)",
    )
    p.add_argument(
        "--denoisers",
        type=_denoisers,
        metavar="NAMES",
        help="table2 only: comma-separated denoisers of tof_fpn_torch.denoise, or all "
        f"(default the paper's: {','.join(E.PAPER_METHODS)}; all: {','.join(denoise.names())})",
    )
    p.add_argument(
        "--noise",
        choices=("own", "input"),
        help="table2 only: k of sigma_D = k / A estimated by each denoiser on its own input "
        "(own, default) or on the unfiltered frame for both columns (input)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--threads",
        type=threads_arg(),
        default=1,
        help="torch CPU threads, at most the CPU count (default %(default)s: the images are small, "
        "and 1 thread does not stall when another job holds the other core)",
    )
    return p


def run(args: argparse.Namespace) -> int:
    for name, experiment in _ONLY.items():
        if getattr(args, name) not in (None, False) and args.experiment != experiment:
            raise UsageError(
                f"--{name.replace('_', '-')} applies to {experiment} only, not {args.experiment}"
            )
    check_output_dir("--out", args.out)
    if args.experiment == "table2":
        return _run_table2(args)
    kw = {}
    if args.seeds is not None or args.quick:
        kw["seeds"] = args.seeds if args.seeds is not None else QUICK_SEEDS
    if args.size is not None or args.quick:
        kw["size"] = args.size if args.size is not None else QUICK_SIZE
    size = kw.get("size", (_TABLE1 if args.experiment == "table1" else _FIG9)["size"].default)
    if args.patch_size > size:
        raise UsageError(
            f"--patch-size must be at most the scene side {size}, got {args.patch_size}"
        )
    if args.patch_distance >= size:
        raise UsageError(
            f"--patch-distance must be below the scene side {size}, got {args.patch_distance}"
        )
    set_threads(args.threads)
    nlm = E.NLMSettings(args.patch_size, args.patch_distance, args.h).validate()
    progress = not args.no_progress
    if args.experiment == "table1":
        result = E.run_table1(
            nlm=nlm,
            compensate_delay=args.compensate_delay,
            progress=progress,
            **kw,
        )
        with output_dirs(args.out) as created:
            paths = E.write_table1(result, args.out)
        report_created(created)
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
        if args.quick:
            kw.update(
                odd_orders=E.QUICK_ODD_ORDERS, even_orders=E.QUICK_EVEN_ORDERS, rhos=E.QUICK_RHOS
            )
        if args.case is not None:
            kw["case"] = args.case
        result = E.run_fig9(nlm=nlm, progress=progress, **kw)
        with output_dirs(args.out) as created:
            paths = E.write_fig9(result, args.out)
        report_created(created)
        print(
            f"{E.CASE_LABELS[result['case']]}: input {result['input_psnr']:.2f} dB, NLM not "
            f"filtered {result['nlm_unfiltered']:.2f} dB"
        )
        for name, b in result["best"].items():
            print(f"  best {name:18s}: {{{b['order']}, {b['rho']:g}}} {b['psnr']:.2f} dB")
    written = ", ".join(join(args.out, p.name) for p in paths.values())
    print(f"wrote {written} ({result['seconds']:.1f} s)")
    return 0


def _run_table2(args: argparse.Namespace) -> int:
    nlm = E.NLMSettings()
    defaults = {"h": nlm.h, "patch_size": nlm.patch_size, "patch_distance": nlm.patch_distance}
    for name in _NOT_TABLE2:
        value = getattr(args, name)
        if value not in (None, False) and value != defaults.get(name, None):
            raise UsageError(f"--{name.replace('_', '-')} does not apply to table2")
    kw = dict(QUICK_TABLE2) if args.quick else {}
    for name in ("size", "frames", "gt_frames"):
        if getattr(args, name) is not None:
            kw[name] = getattr(args, name)
    setup = E.Table2Setup(**kw).validate()
    set_threads(args.threads)
    methods = args.denoisers or E.PAPER_METHODS
    result = E.run_table2(setup, methods, noise=args.noise or "own", progress=not args.no_progress)
    with output_dirs(args.out) as created:
        paths = E.write_table2(result, args.out)
    report_created(created)
    for r in result["rows"]:
        cells = ", ".join(f"{m} {v[0]:.1f}->{v[1]:.1f}" for m, v in r["psnr"].items())
        print(
            f"{r['integration_time_us']:4d} us: LOW {r['low']:.0f} %, IMP {r['imp']:.0f} %; "
            f"PSNR dB (not filtered->filtered): {cells}"
        )
    written = ", ".join(join(args.out, p.name) for p in paths.values())
    print(f"wrote {written} ({result['seconds']:.1f} s)")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, or a parsing error already printed
        return exc.code if isinstance(exc.code, int) else 0
    try:
        return run(args)
    except ValueError as exc:  # a bad argument found after parsing, or bad input
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
