"""How the tuned preset's settling after the measured restart (``FilterConfig.settle_s``) was chosen:
every other setting fixed at the preset, each candidate run on every shared trial with ground truth
whole, from its first motion (BROAD), and cut to start at five drawn moments of its length (0.15, 0.30,
0.45, 0.60, 0.75: a recording that starts mid-motion), VQF on the same steps in the same run. The
objective is the tuning's (:mod:`bench.estimator_tuning`) on the total RMSE, with the cut trials as groups
of their own: ``J = max over groups of mean RMSE(ours) / mean RMSE(VQF)``, groups smartphone and BROAD
whole, BROAD from first motion, and the cut trials. The candidate with the least J is the preset's
(the shortest on a tie). Run: ``python -m bench.estimator_settle [candidates, s]``; docs/estimator.md,
"Starting mid-motion", holds the run that chose it."""

from __future__ import annotations

import argparse
import sys

from bench.bench_estimator import Trial, _trial_of, load_trials
from bench.estimator_choice import choose
from hil.estimation.filter import FilterConfig

CUTS = (0.15, 0.30, 0.45, 0.60, 0.75)
"""Where each trial is cut to start, as fractions of its length."""
CANDIDATES = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0)
"""Settling lengths tried (s)."""


def cases() -> list[tuple[Trial, str]]:
    """Every shared trial whole (group: its family), BROAD's from first motion, and every trial cut at
    :data:`CUTS` (group ``cut``)."""
    out: list[tuple[Trial, str]] = []
    for trial in load_trials(cropped=True):
        out.append((trial, trial.family))
        if trial.family == "BROAD from first motion":
            continue
        for f in CUTS:
            t0 = trial.log.start + f * (trial.log.end - trial.log.start)
            cut = _trial_of(
                trial.log.window(t0, trial.log.end), trial.path, f"{trial.name} from {f:.2f}", trial.group
            )
            out.append((cut, "cut"))
    return out


def table(settles: tuple[float, ...]) -> str:
    """One row per candidate: each group's mean total RMSE (degrees), its ratio to VQF's, and J."""
    return choose("settle_s", cases(), settles, lambda s: FilterConfig.tuned(settle_s=s))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("settles", nargs="*", type=float, default=list(CANDIDATES), help="candidates, s")
    print(table(tuple(ap.parse_args(argv).settles)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
