"""``tof-fpn`` command line: one sub-command per module of this package (the top layer).

May import every other layer; nothing imports it.

Each command module defines ``register(subparsers)``, which adds its parser and sets
``func=<callable(args) -> int>`` as the parser default. Every error is one line on stderr,
``tof-fpn COMMAND: error: ...``, naming the argument, the value and what is allowed: exit status 2
for a bad argument (parsing errors included), 1 when the file system refuses (``OSError``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from .. import __version__
from ..design import RemezConvergenceError

#: Sub-command modules under ``tof_fpn_torch.cli``, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = (
    "design",
    "export",
    "demo",
    "clean",
    "calibrate",
    "convert",
    "diagnose",
)


class _ParseError(Exception):
    """Raised instead of argparse's usage-and-exit; ``main`` prints it as one line."""


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` (sub-command parsers inherit it) whose errors are one line."""

    def error(self, message: str):
        raise _ParseError(f"{self.prog}: error: {message}")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tof-fpn",
        description="Fixed-pattern-noise suppression for Time-of-Flight depth data.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"tof_fpn_torch.cli.{name}").register(sub)
    return parser


def _error(command: str, message: str, status: int) -> int:
    print(f"tof-fpn {command}: error: {message}", file=sys.stderr)
    return status


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``tof-fpn`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _ParseError as exc:  # bad arguments: one line, no usage block
        print(exc, file=sys.stderr)
        return 2
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else 0
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:  # bad input: one line, no traceback
        return _error(args.command, str(exc), 2)
    except RemezConvergenceError as exc:  # a filter the arguments ask for cannot be designed
        filt = " ".join(f"--{k} {getattr(args, k)}" for k in ("order", "rho") if hasattr(args, k))
        return _error(args.command, f"no filter for {filt}: {exc}", 2)
    except OSError as exc:  # the file system refused (permissions, disk full, ...)
        return _error(args.command, str(exc), 1)


if __name__ == "__main__":
    sys.exit(main())
