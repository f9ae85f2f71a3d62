"""``hil``: the host's command line. One entry point, one argparse subcommand per module in this package.

Each subcommand module defines ``register(subparsers)``, which adds its parser and sets ``func`` to a
handler ``(args) -> int``, and an integer ``ORDER`` (where ``hil --help`` lists it; smaller first).
Modules are discovered, so adding a command is adding a module. Heavy imports happen inside handlers so
``hil --help`` stays fast.

SIGTERM and SIGINT both raise ``KeyboardInterrupt`` while a command runs (:mod:`hil.cli._signals`), so a
command ends the same clean way whichever it gets; one that escapes the command ends ``hil`` with
128 + the signal's number (130, 143). ``hil run`` and ``hil replay --port`` catch it in the run and report
it in their summary instead (exit status 1: docs/faults.md).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
from collections.abc import Sequence
from types import ModuleType

from protocol.errors import HilError

from ._parser import ArgumentParser
from ._signals import (
    exit_on_late_signals,
    exit_status,
    ignore_signals_at_last_exit_hook,
    interrupts_raise,
    signal_of,
)


def command_modules() -> list[ModuleType]:
    """The subcommand modules of this package, in ``ORDER`` (then name) order."""
    modules = [
        importlib.import_module(f"{__name__}.{info.name}")
        for info in pkgutil.iter_modules(__path__)
        if not info.name.startswith("_")
    ]
    modules = [m for m in modules if hasattr(m, "register")]
    return sorted(modules, key=lambda m: (getattr(m, "ORDER", 100), m.__name__))


class _VersionAction(argparse.Action):
    """``--version``, worked out only when asked (it runs git: not on every command's start)."""

    def __init__(self, option_strings: Sequence[str], dest: str, help: str | None = None) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=help)

    def __call__(self, parser: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        from hil.version import version_line

        print(version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(
        prog="hil",
        description="Hardware-in-the-loop host for a smartphone-based VSCMG attitude control system.",
        epilog="Run 'hil COMMAND --help' for each command's options and examples.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-vv for debug)")
    parser.add_argument(
        "--version",
        action=_VersionAction,
        help="print the package's version and the checkout's git revision, and exit",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in command_modules():
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None, *, own_process: bool = False) -> int:
    """Run the command ``argv`` names; its exit status. ``own_process``: this process is the command's
    (:func:`entry`): once it has ended, a signal ends the process at once with the command's status
    (:func:`exit_on_late_signals`); otherwise (a test calling it) the caller's handlers come back."""
    said = "hil"  # the command's name once the command line is read: what its last line starts with
    escape_what_stdout_cannot_show()
    try:
        # The handlers first: building the parser imports every command's module (~0.3 s of a run's
        # start), and a Ctrl-C there met Python's own handler: a traceback, and a SIGHUP right after it
        # killed the process (status -1).
        with interrupts_raise(restore=not own_process):
            args = build_parser().parse_args(argv)
            said = f"hil {args.command}"
            level = logging.WARNING - 10 * min(args.verbose, 2)
            logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
            status = int(args.func(args) or 0)
            if own_process:  # at once, in the handlers' block: a signal from here on ends with status
                exit_on_late_signals(status)
    except HilError as exc:
        print(f"{said}: error: {exc}", file=sys.stderr)
        status = 2
    except KeyboardInterrupt as exc:
        print(f"{said}: interrupted ({signal_of(exc).name})", file=sys.stderr)
        status = exit_status(exc)
    if own_process:
        exit_on_late_signals(status)
    return status


def escape_what_stdout_cannot_show() -> None:
    """Characters stdout's encoding cannot show written as escapes (``\\u03b4``, ``\\udcff``), as Python
    writes them to stderr, for every command: a summary's ``δ`` and ``ᵀ`` or a ``°`` on a terminal or pipe
    in a C or Latin-1 locale, and in any locale, UTF-8's too, a path whose name is not UTF-8 (its bytes
    kept as lone surrogates, which no encoding takes). ``hil run``'s summary went unprinted (its lines'
    ``print`` raised a ``UnicodeEncodeError``, a ``ValueError`` its guard against a hung-up terminal passed
    over), ``hil calibrate`` went silent from such a path on, and ``hil report`` took the error for a
    damaged summary.json. UTF-8 with a lenient handler (``surrogateescape``: such a name's own bytes
    written back) shows everything already; a stdout without ``reconfigure`` (replaced by a caller) is left
    as it is."""
    import codecs

    reconfigure = getattr(sys.stdout, "reconfigure", None)
    encoding = codecs.lookup(getattr(sys.stdout, "encoding", None) or "ascii").name
    if not callable(reconfigure) or (encoding == "utf-8" and getattr(sys.stdout, "errors", None) != "strict"):
        return
    reconfigure(errors="backslashreplace")


def entry() -> int:
    """The ``hil`` command's process (its console script, ``python -m hil``)."""
    ignore_signals_at_last_exit_hook()
    try:
        return main(own_process=True)
    except KeyboardInterrupt as exc:  # one that came as main ended, past its handling: said, as any other
        print(f"hil: interrupted ({signal_of(exc).name})", file=sys.stderr)  # (a non-zero status, silent)
        return exit_status(exc)


if __name__ == "__main__":
    sys.exit(entry())
