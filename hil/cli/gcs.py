"""``hil gcs RUN_DIR [RUN_DIR ...]``: the ground-station page for a run directory — finished, killed, or
still being written by another process (followed as it grows). Replays have a timeline to scrub and take no
commands. With two or more, the runs are compared: the first replayed, the others drawn over its plots."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ORDER = 15

EPILOG = """\
examples:
  hil gcs runs/20260101-120000-cubesat-1u           # open a finished run; Ctrl-C to stop serving
  hil gcs runs/20260101-120000-cubesat-1u --gcs :9000
  hil run --out runs/ & hil gcs runs/<its directory>  # follow a run another process is writing
  hil gcs runs/A runs/B runs/C                       # compare: B and C over A's plots, a legend by run

The URL printed at start carries an access token (like Jupyter's); the server listens on the loopback
address unless --gcs names another. docs/gcs.md describes the page.
"""


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "gcs",
        help="ground-station page for a run directory (replay, or follow one being written)",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "run_dir",
        type=Path,
        nargs="+",
        metavar="RUN_DIR",
        help="a run directory (hil run writes them); two or more: compared on one page",
    )
    p.add_argument("--gcs", default="", metavar="HOST:PORT", help="where to listen (default 127.0.0.1:8470)")
    p.add_argument("--no-follow", action="store_true", help="read what is there now; do not wait for more")
    p.set_defaults(func=serve)


def serve(args: argparse.Namespace) -> int:
    from hil.gcs import GroundStation

    runs: list[Path] = args.run_dir
    follow = not args.no_follow
    if len(runs) == 1:
        station = GroundStation.replay(runs[0], bind=args.gcs or None, follow=follow)
    else:
        station = GroundStation.compare(list(runs), bind=args.gcs or None, follow=follow)
    try:
        print(f"ground station: {station.url}", flush=True)
        print(f"serving {', '.join(map(str, runs))} (Ctrl-C to stop)", file=sys.stderr, flush=True)
        while True:
            time.sleep(0.5)
            station.check()
    except KeyboardInterrupt:
        return 0
    finally:
        station.close(linger_s=0.5)
