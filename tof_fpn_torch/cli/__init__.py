"""``tof-fpn`` command line: one sub-command per module of this package (the top layer).

May import every other layer; nothing imports it.

Each command module defines ``register(subparsers)``, which adds its parser and sets
``func=<callable(args) -> int>`` as the parser default.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

#: Sub-command modules under ``tof_fpn_torch.cli``, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = ("design", "export", "reproduce", "demo")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tof-fpn",
        description="Fixed-pattern-noise suppression for Time-of-Flight depth data.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        importlib.import_module(f"tof_fpn_torch.cli.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:  # bad input: one line, no traceback
        print(f"tof-fpn {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
