"""Run every benchmark (or those named) and print one table of figures and ratios against peers."""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from pathlib import Path

from bench.common import Result


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


def main(argv: list[str] | None = None) -> int:
    names = discover()
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("only", nargs="*", help=f"benchmarks to run (default all): {', '.join(names)}")
    parser.add_argument("--quick", action="store_true", help="shorter runs (smoke test of the benchmarks)")
    args = parser.parse_args(argv)
    unknown = set(args.only) - set(names)
    if unknown:
        parser.error(f"unknown benchmark(s): {', '.join(sorted(unknown))}")
    results: list[Result] = []
    failed = 0
    for name in args.only or names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        try:
            module = importlib.import_module(f"bench.bench_{name}")
            results.extend(module.run(quick=args.quick))
        except Exception:  # a broken benchmark must not hide the others' figures
            failed += 1
            traceback.print_exc()
    print(format_table(results))
    for r in results:
        if r.note:
            print(f"note [{r.bench}] {r.name}: {r.note}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
