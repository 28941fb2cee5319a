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

from ..clean import ENGINES, CleanConfig, clean, load_config
from ..clean.steps import FILE_OPTIONS, Option, TableOption, options
from ..clean.work import NoFramesError
from ._common import UsageError, extras_named, int_arg, set_threads, threads_arg


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


def _setting_arg(option: Option):
    """argparse ``type`` of a declared option: parsed to its kind and checked by its setting."""
    setting = option.setting

    def parse(text: str):
        try:
            value = setting.kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {setting.allowed()}, got {text!r}") from None
        try:
            return setting.check(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {setting.allowed()}, got {text!r}") from None

    parse.__name__ = setting.kind.__name__
    return parse


def add_option(group, option: Option | TableOption) -> None:
    """The flag of one declared option (module :mod:`tof_fpn_torch.clean.steps`)."""
    if isinstance(option, TableOption):
        group.add_argument(
            f"--{option.flag}",
            dest=option.name,
            type=_option,
            action="append",
            metavar="KEY=VALUE",
            help=option.help,
        )
        return
    flag, s = option.cli_flag(), option.setting
    if not flag:
        return
    if s.kind is bool:
        on = s.default is not True
        group.add_argument(
            f"--{flag}" if on else f"--no-{flag}",
            dest=option.name,
            action="store_const",
            const=on,
            help=s.help if on else f"turn off {s.help}",
        )
        if s.default is None:  # decided by a preset: both ways can be asked for
            group.add_argument(
                f"--no-{flag}", dest=option.name, action="store_const", const=False,
                help=f"turn off {s.help.split(' (default')[0]}",
            )  # fmt: skip
        return
    choices = option.cli_choices() if option.cli_choices is not None else (s.choices or None)
    group.add_argument(
        f"--{flag}",
        dest=option.name,
        type=None if choices else _setting_arg(option),
        choices=choices,
        metavar="FILE" if option.path else None,
        help=s.help,
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
    for option in options():
        add_option(g, option)
    f = p.add_argument_group("files and execution")
    for option in FILE_OPTIONS:
        add_option(f, option)
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
    changes: dict = {}
    for option in [*options(), *FILE_OPTIONS]:
        given = vars(args).get(option.name)
        if isinstance(option, TableOption):
            table = dict(getattr(base, option.name))
            follows = vars(args).get(option.follows) if option.follows else None
            if follows is not None and follows != getattr(base, option.follows):
                table = {}  # another denoiser: the file's options were the old one's
            table.update(dict(given or []))
            changes[option.name] = table
        elif given is not None:
            changes[option.name] = os.path.abspath(given) if option.path else given
    return base.replace(**changes)


def run(args: argparse.Namespace) -> int:
    if args.engine == "local" and (args.concurrency or args.ray_address):
        raise UsageError("--concurrency and --ray-address need --engine ray")
    config = config_from_args(args)
    if args.threads is not None:
        set_threads(args.threads)
    try:
        with extras_named():
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
    except NoFramesError as exc:  # every file's reason, one line each, then the error
        if not exc.failures:
            raise
        for name, why in exc.failures:
            print(f"failed: {name}: {why}", flush=True)
        raise ValueError(
            f"{exc.HEADLINE} ({len(exc.failures)} file(s), each with its reason above)"
        ) from None
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
