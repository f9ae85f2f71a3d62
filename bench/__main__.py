"""Run every benchmark (or those named) and print one table of figures and ratios against peers.

``--json FILE`` also writes every figure as a JSON list of objects ``{"bench", "name", "value", "unit",
"peer", "peer_value", "ratio"}`` (``ratio``: ours relative to the peer, > 1 better; null without a peer;
a value that is not a finite number is null), so figures can be compared across runs and machines.

A benchmark whose peer is not installed (the peers are optional extras: ``pip install -e '.[bench]'``,
Basilisk ``'.[basilisk]'``) is reported as skipped with the command that installs it, and the others run.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import re
import sys
import traceback
from pathlib import Path
from typing import Any

from bench.common import Result
from firmware_sim.avr.build import ToolchainMissing

PEER_EXTRAS = {
    "pymavlink": "bench",
    "vqf": "bench",
    "ahrs": "bench",
    "imufusion": "bench",
    "atheris": "bench",
    "Basilisk": "basilisk",
}
"""The peers' top-level modules and the extra of pyproject.toml that installs each."""

_NO_MODULE = re.compile(r"No module named '([\w.]+)'")


def discover() -> list[str]:
    return sorted(p.stem.removeprefix("bench_") for p in Path(__file__).parent.glob("bench_*.py"))


def format_table(results: list[Result]) -> str:
    header = ("bench", "figure", "ours", "unit", "peer", "peer value", "ours/peer")
    rows = [header]
    for r in results:
        ratio = r.ratio
        rows.append(
            (
                r.bench,
                r.name,
                f"{r.value:.4g}",
                r.unit,
                r.peer,
                "" if r.peer_value is None else f"{r.peer_value:.4g}",
                "" if ratio is None else f"{ratio:.2f}x",
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)) for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _number(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def as_json(results: list[Result]) -> list[dict[str, Any]]:
    """The figures as JSON-ready objects (see the module docstring)."""
    return [
        {
            "bench": r.bench,
            "name": r.name,
            "value": _number(r.value),
            "unit": r.unit,
            "peer": r.peer or None,
            "peer_value": _number(r.peer_value),
            "ratio": _number(r.ratio),
        }
        for r in results
    ]


def missing_peer(exc: BaseException) -> tuple[str, str] | None:
    """(module, extra) when ``exc`` says a peer's module is not installed — raised here, or reported by a
    benchmark's helper process in its message; None for any other error."""
    names = []
    for err in (exc, exc.__cause__, exc.__context__):
        if isinstance(err, ImportError) and err.name:
            names.append(err.name)
        if err is not None:
            names += _NO_MODULE.findall(str(err))
    for name in names:
        top = name.split(".")[0]
        if top in PEER_EXTRAS:
            return top, PEER_EXTRAS[top]
    return None


def main(argv: list[str] | None = None) -> int:
    names = discover()
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("only", nargs="*", help=f"benchmarks to run (default all): {', '.join(names)}")
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test of the benchmarks)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write every figure to FILE as JSON")
    args = parser.parse_args(argv)
    unknown = set(args.only) - set(names)
    if unknown:
        parser.error(f"unknown benchmark(s): {', '.join(sorted(unknown))}")
    results: list[Result] = []
    failed = 0
    skipped: list[str] = []
    for name in args.only or names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        try:
            module = importlib.import_module(f"bench.bench_{name}")
            results.extend(module.run(quick=args.quick))
        except ToolchainMissing as exc:  # the firmware's benchmarks on a machine without the AVR toolchain
            skipped.append(f"[{name}]: {exc}")
            print(f"skipped {skipped[-1]}", file=sys.stderr, flush=True)
        except Exception as exc:  # a broken benchmark must not hide the others' figures
            peer = missing_peer(exc)
            if peer is None:
                failed += 1
                traceback.print_exc()
                continue
            module_name, extra = peer
            skipped.append(f"[{name}]: its peer {module_name} is not installed: pip install -e '.[{extra}]'")
            print(f"skipped {skipped[-1]}", file=sys.stderr, flush=True)
    print(format_table(results))
    for r in results:
        if r.note:
            print(f"note [{r.bench}] {r.name}: {r.note}")
    for line in skipped:
        print(f"skipped {line}")
    if args.json is not None:
        args.json.write_text(json.dumps(as_json(results), indent=1, allow_nan=False) + "\n")
        print(f"figures written to {args.json}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
