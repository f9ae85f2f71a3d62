"""A campaign's figures (matplotlib on an Agg canvas: no display, no pyplot state), drawn from its output
directory alone, so they can be redrawn at any time, also while a campaign is still running:

- ``histograms.png``: every metric over the ok runs, the requirement's limit as a red line;
- ``envelopes.png``: pointing error and estimator error against time across runs: median, 95th
  percentile and the extremes (from the decimated traces), log scale;
- ``scatter.png``: each dispersed parameter against a metric (default the final pointing error), one panel
  per parameter ordered by the strength of their rank correlation (Spearman ρ in the title), the worst 5 %
  of runs in red with their run index beside the worst few.
"""

from __future__ import annotations

import math
from pathlib import Path

from hil.plots.streamed import PLOT_LIMIT  # first: hil.plots imports matplotlib whatever MPLBACKEND says

# isort: split
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from hil.files.output import make_dir, replace_file

from .metrics import METRICS, TRACES
from .store import Results, checked_write, read_manifest, read_runs, read_traces
from .summary import requirements

WORST_FRACTION = 0.05
MAX_SCATTER_PANELS = 16


def plot_campaign(
    out_dir: str | Path, settle_deg: float, max_gimbal_rate: float, metric: str = "final_error_deg"
) -> dict[str, Path]:
    """Draw every figure the results allow into ``out_dir/plots``; returns name → path."""
    out = Path(out_dir)
    results = read_runs(out)
    info = read_manifest(out)
    plots = make_dir(out / "plots")  # a file of that name is a ConfigError naming it, not a traceback
    drawn: dict[str, Path] = {}
    if results.ok.any():
        limits = {m: lim for m, lim in requirements(info["duration_s"], settle_deg, max_gimbal_rate).values()}
        drawn["histograms"] = _histograms(results, limits, plots / "histograms.png")
        index, traces = read_traces(out, keep=results.index[results.ok])
        if len(index):
            drawn["envelopes"] = _envelopes(
                traces, float(info["trace_hz"]), settle_deg, plots / "envelopes.png"
            )
        if results.parameter_columns():
            drawn["scatter"] = _scatter(results, metric, plots / "scatter.png")
    return drawn


def _grid(count: int, ncols: int, size: tuple[float, float]) -> tuple[Figure, list]:
    nrows = max(1, math.ceil(count / ncols))
    fig = Figure(figsize=(size[0] * ncols, size[1] * nrows))
    axes = [fig.add_subplot(nrows, ncols, k + 1) for k in range(count)]
    return fig, axes


def _save(fig: Figure, path: Path) -> Path:
    """Draw ``fig`` into ``path``, written beside it and renamed over it
    (:func:`~hil.files.output.replace_file`: a link there is replaced, never written through); a write the
    OS refuses (a full disk, a directory of that name) names the file."""
    FigureCanvasAgg(fig)
    fig.tight_layout()
    checked_write(path, lambda: replace_file(path, lambda f: fig.savefig(f, dpi=100, format="png")))
    return path


def _histograms(results: Results, limits: dict[str, float], path: Path) -> Path:
    names = [m for m in METRICS if m in results.values]
    fig, axes = _grid(len(names), 4, (3.6, 2.8))
    for ax, name in zip(axes, names, strict=True):
        values = results.values[name][results.ok]
        finite = values[_plottable(values)]
        never = int(np.sum(np.isinf(values)))
        off_scale = len(values) - len(finite) - never - int(np.sum(np.isnan(values)))
        if len(finite):
            edges = _bin_edges(finite, min(40, max(5, len(finite) // 5)))
            ax.hist(finite, bins=edges, color="tab:blue", alpha=0.8)
        if name in limits:
            ax.axvline(limits[name], color="r", ls="--", lw=1.0, label="requirement")
            ax.legend(fontsize=7)
        notes = [f"{never} never"] * bool(never) + [f"{off_scale} off the scale"] * bool(off_scale)
        ax.set_title(name + (f" ({', '.join(notes)})" if notes else ""), fontsize=9)
        ax.grid(alpha=0.3)
    fig.suptitle(f"{int(results.ok.sum())} ok runs of {len(results)}")
    return _save(fig, path)


def _plottable(values: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Where ``values`` can be drawn: finite, within ±:data:`PLOT_LIMIT`."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(values) & (np.abs(values) <= PLOT_LIMIT)


def _varies(values: NDArray[np.float64]) -> bool:
    """Whether the drawable ``values`` take more than one value."""
    shown = values[_plottable(values)]
    return len(shown) > 1 and bool(np.ptp(shown) > 0)


def _bin_edges(values: NDArray[np.float64], count: int) -> NDArray[np.float64]:
    """``count`` bins over ``values`` (finite), as numpy makes them; values it cannot split into that
    many bins get wider ones about their centre, at least numpy's own ±0.5 for equal values. A metric
    equal in every run up to rounding (``peak_error_deg``, the slew's angle, 19.99999999999998 and
    19.999999999999982) had numpy refuse ("Too many bins for data range") and the campaign end in a
    ValueError after its last run."""
    try:
        return np.histogram_bin_edges(values, bins=count)
    except ValueError:  # a span of a few ulps (or one beyond the largest float) is no range of bins
        pass
    lo, hi = float(values.min()), float(values.max())
    centre = lo / 2 + hi / 2
    half = max(0.5, abs(centre) * 1e-6, hi / 2 - lo / 2)
    return centre + half * np.linspace(-1.0, 1.0, count + 1)  # not linspace(lo, hi): hi - lo may overflow


def _envelopes(traces: NDArray[np.float32], trace_hz: float, settle_deg: float, path: Path) -> Path:
    t = np.arange(traces.shape[-1]) / trace_hz
    fig, axes = _grid(len(TRACES), 1, (9.0, 3.2))
    titles = {"error_deg": "pointing error to the target", "estimate_error_deg": "estimator attitude error"}
    with np.errstate(all="ignore"):
        for ax, k, name in zip(axes, range(len(TRACES)), TRACES, strict=True):
            runs = np.asarray(traces[:, k, :], dtype=float)
            floor = 1e-4  # log scale: a perfect zero is drawn at the floor
            lo = np.maximum(np.nanmin(runs, axis=0), floor)
            ax.fill_between(t, lo, np.nanmax(runs, axis=0), color="tab:blue", alpha=0.15, label="min-max")
            ax.plot(t, np.maximum(np.nanpercentile(runs, 95, axis=0), floor), color="tab:orange", label="p95")
            ax.plot(t, np.maximum(np.nanmedian(runs, axis=0), floor), color="tab:blue", label="median")
            if name == "error_deg":
                ax.axhline(settle_deg, color="r", ls="--", lw=0.8, label="settle requirement")
            ax.set_yscale("log")
            ax.set_ylabel("deg")
            ax.set_title(f"{titles.get(name, name)} across {_runs_traced(runs)}", fontsize=10)
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time from the slew's start (s)")
    return _save(fig, path)


def _runs_traced(runs: NDArray[np.float64]) -> str:
    """How many runs (rows of ``runs``, (runs, samples), NaN past a run's end) an envelope is drawn
    across, said honestly: "across 24 runs" was said of an envelope whose later part only some of them
    reach (a run that failed or was cut short ends its trace there), or none (a run that failed before
    its slew); how many reach the end, and how many have no trace at all, are said beside."""
    finite = np.isfinite(runs)
    traced = int(np.count_nonzero(finite.any(axis=1)))
    at_end = int(np.count_nonzero(finite[:, -1])) if runs.shape[1] else 0
    said = f"{len(runs)} runs"
    notes = []
    if at_end < traced:
        notes.append(f"{traced - at_end} ended early: {at_end} at the end")
    if traced < len(runs):
        notes.append(f"{len(runs) - traced} with no trace")
    return f"{said} ({'; '.join(notes)})" if notes else said


def _scatter(results: Results, metric: str, path: Path) -> Path:
    ok = results.ok & _plottable(results.values.get(metric, np.full(len(results), np.nan)))
    y = results.values[metric][ok]
    index = results.index[ok]
    params = [c for c in results.parameter_columns() if _varies(results.values[c][ok])]
    ranked = sorted(((abs(_spearman(results.values[c][ok], y)), c) for c in params), reverse=True)
    ranked = ranked[:MAX_SCATTER_PANELS]
    fig, axes = _grid(max(len(ranked), 1), 4, (3.6, 2.8))
    n_worst = max(1, int(math.ceil(WORST_FRACTION * len(y))))
    worst = np.argsort(y)[::-1][:n_worst]
    is_worst = np.zeros(len(y), bool)
    is_worst[worst] = True
    for ax, (_, name) in zip(axes, ranked, strict=False):
        x = results.values[name][ok]
        shown = _plottable(x)
        ax.scatter(x[~is_worst & shown], y[~is_worst & shown], s=6, color="tab:blue", alpha=0.6)
        ax.scatter(x[is_worst & shown], y[is_worst & shown], s=14, color="tab:red", label=f"worst {n_worst}")
        for k in (k for k in worst[:3] if shown[k]):
            ax.annotate(str(index[k]), (x[k], y[k]), fontsize=6, xytext=(2, 2), textcoords="offset points")
        ax.set_title(f"{name}  (ρ = {_spearman(x, y):+.2f})", fontsize=8)
        ax.set_ylabel(metric, fontsize=7)
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.3)
    if ranked:
        axes[0].legend(fontsize=7)
    else:
        axes[0].set_title("no dispersed parameter varies over the ok runs", fontsize=9)
    fig.suptitle(f"dispersed parameters against {metric}, strongest rank correlation first")
    return _save(fig, path)


def _spearman(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    """Spearman's rank correlation (0 when either side is constant)."""
    rx, ry = _ranks(x), _ranks(y)
    sx, sy = np.std(rx), np.std(ry)
    if sx == 0 or sy == 0:
        return 0.0
    return float(np.mean((rx - rx.mean()) * (ry - ry.mean())) / (sx * sy))


def _ranks(v: NDArray[np.float64]) -> NDArray[np.float64]:
    order = np.argsort(v, kind="stable")
    ranks = np.empty(len(v))
    ranks[order] = np.arange(len(v))
    return ranks
