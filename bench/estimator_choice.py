"""The one procedure by which a single setting of the tuned preset is chosen after the tuning
(:mod:`bench.estimator_tuning`), every other setting fixed: each candidate run on the same cases, VQF on
the same steps in the same run, ``J = max over groups of mean RMSE_total(ours) / mean RMSE_total(VQF)``
(a case where either has no evaluated sample left out of both), the least J among the eligible candidates
chosen (the first given on a tie). Used by :mod:`bench.estimator_settle` and :mod:`bench.estimator_rates`."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bench.bench_estimator import Trial, score, vqf_quats
from hil.estimation.filter import AttitudeFilter, FilterConfig


def choose(
    setting: str,
    runs: list[tuple[Trial, str]],
    candidates: tuple[float, ...],
    config: Callable[[float], FilterConfig],
    eligible: Callable[[float], bool] = lambda value: True,
) -> str:
    """A table (markdown) with one row per candidate value of ``setting`` — each group's mean total RMSE
    (degrees) and its ratio to VQF's, and J — over ``runs`` (a trial and its group), the filter for a value
    being ``config(value)``; its last line names the chosen value."""
    groups = np.array([g for _, g in runs])
    names = list(dict.fromkeys(groups))
    vqf = np.array([score(t, vqf_quats(t)).total for t, _ in runs])
    lines = [f"{setting} | " + " | ".join(names) + " | J", "---|" + "---|" * len(names) + "---"]
    lines.append("VQF | " + " | ".join(f"{np.nanmean(vqf[groups == g]):.2f}" for g in names) + " | ")
    best: tuple[float, float] | None = None
    for value in candidates:
        cfg = config(value)
        ours = np.array([score(t, AttitudeFilter(cfg).run(t.steps).quat).total for t, _ in runs])
        both = np.isfinite(ours) & np.isfinite(vqf)  # a case with no evaluated sample left is no case
        means = [(np.mean(ours[both & (groups == g)]), np.mean(vqf[both & (groups == g)])) for g in names]
        j = float(max(o / v for o, v in means))
        cells = [f"{o:.2f} ({o / v:.3f}x)" for o, v in means]
        lines.append(f"{value:g} | " + " | ".join(cells) + f" | {j:.4f}")
        if eligible(value) and (best is None or j < best[1]):
            best = (value, j)
    if best is None:
        lines.append("\nno candidate is eligible")
    else:
        lines.append(
            f"\nleast J: {setting} = {best[0]:g} (J {best[1]:.4f}); {int(np.isfinite(vqf).sum())} cases"
        )
    return "\n".join(lines)
