"""``tof-fpn clean INPUT OUTPUT``: the FPN pipeline over a file, a directory tree or an HDF5 file.

Stages and settings come from ``--config FILE.toml`` (format: :mod:`tof_fpn_torch.clean.config`)
and flags (a flag wins over the file); the resolved configuration is saved as
``OUTPUT/clean.toml`` with the package version. Exit status: 0; 1 when some files failed (their
count printed, their reasons in ``OUTPUT/manifest.jsonl``); 2 for a bad argument, an INPUT with
nothing to clean or an OUTPUT that would overwrite INPUT; ``128 + signal`` when stopped by
SIGTERM / SIGINT (run the same command again to resume).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the same parser as a package
    import tomli as tomllib

from ..clean import CHOICES, DENOISERS, ENGINES, CleanConfig, clean, load_config
from ..clean.config import FLYING
from ._common import UsageError, float_arg, int_arg, set_threads, threads_arg

#: ``--denoise`` values
DENOISE_CHOICES = ("none", *sorted(DENOISERS))


def _option(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` with a TOML value (``h=0.8``, ``kernel="box"`` or ``kernel=box``)."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip().isidentifier():
        raise argparse.ArgumentTypeError(f"must be KEY=VALUE, got {text!r}")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return key.strip(), parsed


def _flying_arguments(g) -> None:
    """``--flying`` and ``--flying-confidence`` in the stage group ``g``."""
    g.add_argument("--flying", choices=FLYING, help="mixed pixels at depth edges (default off)")
    g.add_argument(
        "--flying-confidence",
        action="store_true",
        help="write the flying-pixel confidence map beside each output "
        "(<output stem>.flying_confidence.npy, float32 frames x H x W)",
    )


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "clean",
        help="clean a file, a directory tree or an HDF5 file of depth frames (resumable)",
        description="Broadband destriping, the notch stage (from the design or from the data), "
        "fusion and a denoiser, any subset, over INPUT (a frame file or a directory tree) into "
        "the directory OUTPUT: same names, dtypes, units, shapes and metadata, depth cleaned. "
        "Never overwrites INPUT; atomic writes; a killed run restarted skips finished files; "
        "OUTPUT/manifest.jsonl records every file.",
    )
    p.add_argument(
        "input",
        metavar="INPUT",
        help="a frame file, a camera file (.mkv, .bag, ROS 2 bag, ADI raw) or a directory",
    )
    p.add_argument("output", metavar="OUTPUT", help="output directory (made if missing)")
    p.add_argument("--config", metavar="FILE", help="TOML configuration (flags override it)")
    g = p.add_argument_group(
        "stages (default: --stage auto, every piece measured on the first frames of INPUT)"
    )
    g.add_argument(
        "--stage",
        choices=CHOICES["stage"],
        help="auto: notch, fusion and destriping measured on the data (default); paper: the "
        "paper's CamCube notch stage with its 70 / 350 fusion",
    )
    g.add_argument("--destripe", choices=CHOICES["destripe"], help="broadband offsets")
    g.add_argument("--notch", choices=CHOICES["notch"], help="periodic stripes")
    g.add_argument("--fusion", choices=CHOICES["fusion"], help="eq. (11) amplitude fusion")
    g.add_argument("--denoise", choices=DENOISE_CHOICES, help="denoiser after the FPN stage")
    _flying_arguments(g)
    g.add_argument(
        "--pattern",
        metavar="FILE",
        help="a fixed pattern from tof-fpn calibrate, removed from every frame first",
    )
    g.add_argument(
        "--denoise-opt",
        type=_option,
        action="append",
        metavar="KEY=VALUE",
        help="a denoiser option, e.g. h=0.8 (repeatable)",
    )
    g.add_argument("--order", type=int_arg(1), help="notch filter order")
    g.add_argument("--rho", type=float_arg(0.0, open_lo=True), help="transition half-width / pi")
    g.add_argument("--no-gate", action="store_true", help="apply the notch to every frame")
    g.add_argument("--camera", help="camera profile of --fusion camera (e.g. adtf3175)")
    g.add_argument("--low", type=float_arg(0.0), help="--fusion manual: low threshold")
    g.add_argument("--high", type=float_arg(0.0, open_lo=True), help="--fusion manual: high")
    g.add_argument("--calibration-frames", type=int_arg(1), help="frames measured by data stages")
    g.add_argument("--temporal", action="store_true", help="filter each recording over time")
    f = p.add_argument_group("files and execution")
    f.add_argument("--batch", type=int_arg(1), help="files per group, frames per batch")
    f.add_argument("--depth-scale", type=float_arg(0.0, open_lo=True), help="metres per unit")
    f.add_argument("--height", type=int_arg(1), help="rows of raw .bin / .raw frames")
    f.add_argument("--width", type=int_arg(1), help="columns of raw .bin / .raw frames")
    f.add_argument(
        "--rounding",
        choices=CHOICES["rounding"],
        help="integer outputs: dither (default: sub-unit corrections survive in the mean) or "
        "nearest",
    )
    f.add_argument(
        "--output-scale",
        type=float_arg(0.0, open_lo=True),
        metavar="M",
        help="integer outputs: metres per stored unit, e.g. 0.0001 (default: the input's)",
    )
    f.add_argument("--no-figure", action="store_true", help="do not draw OUTPUT/report.png")
    f.add_argument(
        "--workers", type=int_arg(0, 256), default=0, help="DataLoader workers (default 0)"
    )
    f.add_argument("--device", default="auto", help="auto (GPU if any), cpu or cuda[:N]")
    f.add_argument("--engine", choices=ENGINES, default="local", help="default %(default)s")
    f.add_argument("--concurrency", type=int_arg(1), help="Ray actors running the pipeline")
    f.add_argument("--ray-address", help="Ray cluster address (default: RAY_ADDRESS or local)")
    f.add_argument("--threads", type=threads_arg(), help="torch CPU threads of this process")
    f.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def config_from_args(args: argparse.Namespace) -> CleanConfig:
    """The file's configuration (or the defaults) with the flags given applied."""
    base = load_config(args.config) if args.config else CleanConfig()
    options = dict(base.denoise_options)
    if args.denoise is not None and args.denoise != base.denoise:
        options = {}
    options.update(dict(args.denoise_opt or []))
    return base.replace(
        stage=args.stage,
        destripe=args.destripe,
        notch=args.notch,
        fusion=args.fusion,
        denoise=args.denoise,
        pattern=None if args.pattern is None else os.path.abspath(args.pattern),
        denoise_options=options,
        order=args.order,
        rho=args.rho,
        gate=False if args.no_gate else None,
        camera=args.camera,
        low=args.low,
        high=args.high,
        calibration_frames=args.calibration_frames,
        batch=args.batch,
        depth_scale=args.depth_scale,
        height=args.height,
        width=args.width,
        rounding=args.rounding,
        output_scale=args.output_scale,
        temporal=True if args.temporal else None,
        flying=args.flying,
        flying_confidence=True if args.flying_confidence else None,
    )


def run(args: argparse.Namespace) -> int:
    if args.engine == "local" and (args.concurrency or args.ray_address):
        raise UsageError("--concurrency and --ray-address need --engine ray")
    config = config_from_args(args)
    if args.threads is not None:
        set_threads(args.threads)
    report = clean(
        args.input,
        args.output,
        config,
        workers=args.workers,
        device=args.device,
        engine=args.engine,
        progress=False if args.quiet else None,
        concurrency=args.concurrency,
        ray_address=args.ray_address,
        figure=not args.no_figure,
    )
    if report.created:
        print(f"created directory {args.output}")
    print(report.summary())
    prefix = "tof-fpn clean: error:"
    if report.interrupted is not None:
        name = signal.Signals(report.interrupted).name
        left = report.jobs - report.already_done - report.done - report.failed
        print(
            f"{prefix} stopped by {name} with {max(left, 0)} file(s) left; run the same command "
            f"again to resume (finished files are skipped)",
            file=sys.stderr,
        )
    elif report.failed:
        print(
            f"{prefix} {report.failed} of {report.jobs} file(s) failed (reasons above and in "
            f"{os.path.join(args.output, 'manifest.jsonl')})",
            file=sys.stderr,
        )
    return report.status
