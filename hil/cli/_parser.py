"""The command lines' argument parser: argparse's, with a negative number in any spelling taken as a value.

argparse takes an argument that starts with ``-`` for an option unless it looks like a negative number,
and its idea of one (Python 3.11: ``-1``, ``-1.5``, ``-.5``) leaves out exponents and the words ``float``
reads: ``hil replay log --window -1e300 5`` ended "argument --window: expected 2 arguments" and
``--pace -1e-3`` "expected one argument", before the option's own check could say what is wrong with the
value. Here ``-1e300``, ``-1E-3``, ``-1.``, ``-inf`` and ``-nan`` are values, judged by the option's type
and checks like any other (none of the project's commands has an option spelled like a number).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

NEGATIVE_NUMBER = re.compile(r"^-(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|inf|infinity|nan)$", re.IGNORECASE)
"""What argparse takes for a negative number (a value), not an option: whatever ``float`` reads after a
minus sign, in ASCII."""


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose negative numbers are :data:`NEGATIVE_NUMBER`; its subcommands'
    parsers are of this class too (``add_subparsers`` makes them of the parser's own type)."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._negative_number_matcher = NEGATIVE_NUMBER


def given_path(text: str) -> Path:
    """An output path typed on the command line: any but the empty one. ``Path("")`` is ``.``: ``--out ""``
    (a shell variable left unset, ``--out "$OUT"``) wrote a replay's or a campaign's files into the
    current directory — removing a replay's earlier outputs there first — instead of being refused."""
    if not text:  # a name of spaces is a name (``--out " "`` makes that folder)
        raise argparse.ArgumentTypeError(
            f"{text!r} is an empty path (an unset shell variable?): give a folder or file name"
        )
    return Path(text)
