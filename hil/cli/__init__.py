"""``hil``: the host's command line. One entry point, one argparse subcommand per module in this package.

Each subcommand module defines ``register(subparsers)``, which adds its parser and sets ``func`` to a
handler ``(args) -> int``. Heavy imports happen inside handlers so ``hil --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from protocol.errors import HilError

# Subcommand modules, in the order ``hil --help`` lists them.
COMMANDS: tuple[str, ...] = ("selftest",)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hil",
        description="Hardware-in-the-loop host for a smartphone-based VSCMG attitude control system.",
        epilog="Run 'hil COMMAND --help' for each command's options and examples.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except HilError as exc:
        print(f"hil {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"hil {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
