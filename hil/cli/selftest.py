"""``hil selftest``: check this installation's protocol codec against the canonical test vectors."""

from __future__ import annotations

import argparse
from pathlib import Path

ORDER = 90


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "selftest",
        help="check the protocol codec against fixtures/protocol_vectors.json",
        description="Encode and decode every canonical frame of the protocol test vectors and report.",
        epilog="example: hil selftest",
    )
    # The default is resolved in run(): hil.scenario.paths imports the scenario package (and numba with
    # it), which building every command's parser (`hil run --help`) must not pay for.
    p.add_argument("--vectors", type=Path, help="vectors file (default: fixtures/protocol_vectors.json)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The vectors file is read as every document hil reads (:func:`~hil.files.bounded.read_document`:
    bounded, a device or a FIFO refused, its JSON's nesting and integers bounded): one that cannot be
    read is an :class:`InputFormatError` naming it (status 2); vectors that fail are status 1."""
    from hil.files.bounded import load_json, read_document
    from hil.scenario.paths import FIXTURES
    from protocol.errors import InputFormatError
    from protocol.messages import CATALOGUE, SCHEMA_HASH
    from protocol.vectors import check_document

    vectors = args.vectors if args.vectors is not None else FIXTURES / "protocol_vectors.json"
    document = load_json(read_document(vectors, InputFormatError, "vectors file"), str(vectors))
    results = check_document(document)
    failed = [r for r in results if not r.ok]
    for r in failed:
        print(f"FAIL {r.name}: {r.detail}")
    print(
        f"protocol: {len(CATALOGUE)} messages, schema hash {SCHEMA_HASH:#010x}; "
        f"{len(results) - len(failed)}/{len(results)} vectors pass ({vectors})"
    )
    return 1 if failed else 0
