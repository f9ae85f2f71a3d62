"""A run directory's figures (``hil run`` draws them at the end, ``hil report`` again): the paper's two
estimator figures (simulated runs, where the truth is known), pointing and tracking error, gimbal angles and
rates, rotor speeds, pulse widths, battery voltage and the singularity measure δ — each from
``telemetry.csv``, with the operator's commands, the slew and the faults of ``events.jsonl`` marked
(:mod:`hil.plots.markers`); a figure whose columns a run lacks is not drawn (:func:`plot_run` returns
those it drew).
The telemetry is read a block at a time, only the columns drawn, each thinned as it comes
(:class:`hil.plots.streamed.MinMaxStream`): memory holds the figures' points, not the run."""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Collection, Sequence
from functools import partial
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D

from hil.files.output import make_dir
from hil.plots.estimator import _dots, _figure, _save
from hil.plots.forked import draw_shared
from hil.plots.markers import draw_markers, run_markers
from hil.plots.streamed import PLOT_LIMIT, MinMaxStream
from hil.runtime.runlog import TelemetryBlocks, iter_events, read_summary
from protocol.errors import InputFormatError
from protocol.messages import MAX_UNITS


def _units(columns: Collection[str], prefix: str) -> list[str]:
    """The per-unit columns ``prefix0`` .. of ``columns``, in unit order: a unit a board can have only
    (below :data:`~protocol.messages.MAX_UNITS`; a header of 20 000 ``gimbal_angle_N`` drew 20 000 lines,
    174 s and 786 MB) — the rest are not drawn (:func:`not_units` counts them)."""
    found = [c for c in columns if c.startswith(prefix) and _unit(c[len(prefix) :]) is not None]
    return sorted(found, key=lambda c: int(c[len(prefix) :]))


def _unit(suffix: str) -> int | None:
    """A unit's number from a column's suffix: plain ASCII digits, short, below MAX_UNITS; else None."""
    if not (suffix.isascii() and suffix.isdigit()) or len(suffix) > 3:
        return None
    return int(suffix) if int(suffix) < MAX_UNITS else None


def not_units(header: Sequence[str]) -> int:
    """The columns of ``header`` named as a figure's per-unit column with a unit no board has (a number of
    ``MAX_UNITS`` or more): not drawn, counted."""
    prefixes = [p for *_, spec, _, _ in _FIGURES for p in ((spec,) if isinstance(spec, str) else spec)]
    prefixes = [p for p in prefixes if p.endswith("_")]
    return sum(
        1
        for c in header
        for p in prefixes
        if c.startswith(p) and c[len(p) :].isdigit() and _unit(c[len(p) :]) is None
    )


Series = Callable[[str], tuple[np.ndarray, np.ndarray]]
"""A column's points to draw, by its name: (t, y), thinned (:class:`hil.plots.streamed.MinMaxStream`)."""


def _lines(ax: Axes, series: Series, names: list[str], label: str, log: bool = False) -> None:
    """A line per column; on a ``log`` scale, its values ≤ 0 marked at the axes' foot (:func:`_at_foot`)."""
    for name in names:
        suffix = name.rsplit("_", 1)[-1]
        t, y = series(name)
        (line,) = ax.plot(t, y, lw=0.8, label=f"{label} {suffix}" if suffix.isdigit() else name)
        _dots(ax, t, y, line)  # a reading alone between gaps: a dot, not nothing
        if log:
            _at_foot(ax, t, y, line)


def _at_foot(ax: Axes, t: np.ndarray, y: np.ndarray, line: Line2D) -> None:
    """The times at which ``y`` (N,) is ≤ 0 as triangles of ``line``'s colour on the foot of a log-scaled
    axes: a log scale has no place for them, and matplotlib leaves them out — a pointing error of exactly
    0 (a target the spacecraft already held) was drawn as no data."""
    with np.errstate(invalid="ignore"):
        low = y <= 0
    if low.any():
        ax.plot(
            t[low], np.zeros(int(low.sum())), ls="none", marker="v", ms=4, color=line.get_color(),
            transform=ax.get_xaxis_transform(), clip_on=False,
        )  # fmt: skip


_FIGURES: tuple[tuple[str, str, str, str | tuple[str, ...], str, bool], ...] = (
    # name, title, y label, its columns (a prefix: a column per unit), line label, log scale
    ("attitude_error", "Attitude estimation error (principal angle of Q = R R̂ᵀ)",
     "attitude estimation error (deg)", ("est_err_deg",), "est err", False),
    ("rate_error", "Angular velocity estimation error", "|Ω − Ω̂| (rad/s)", ("rate_err",), "rate err", False),
    ("pointing_error", "Pointing error (to the target) and tracking error (to the reference)", "error (deg)",
     ("point_err_deg", "track_err_deg"), "", True),
    ("gimbal_angles", "Gimbal angles", "angle (rad)", "gimbal_angle_", "gimbal", False),
    ("gimbal_rates", "Gimbal rates", "rate (rad/s)", "gimbal_rate_", "gimbal", False),
    ("rotor_speeds", "Rotor speeds", "speed (rad/s)", "rotor_speed_", "rotor", False),
    ("pulse_widths", "Pulse widths on the board's outputs", "width (µs)", ("pulse_gimbal_", "pulse_rotor_"),
     "pulse", False),
    ("battery", "Battery voltage", "voltage (V)", ("battery_v",), "battery", False),
    ("delta", "Singularity measure δ", "δ", ("delta",), "δ", False),
)  # fmt: skip
"""The figures of :func:`plot_run`, in order. A column name ending in ``_`` is a prefix: it stands for its
per-unit columns, in unit order."""


def warm() -> None:
    """Draw one figure as :func:`plot_run` draws them and throw it away: a process's first figure pays for
    loading the fonts and filling matplotlib's text and path caches (0.1–0.25 s here), which ``hil run``'s
    plotter does on its own core while the run runs, so that the run's figures (drawn by forks of it,
    which inherit the caches) do not."""
    t = np.linspace(0.0, 10.0, 200)
    columns = {"x_0": np.sin(t), "x_1": np.cos(t)}
    fig, ax = _figure("Warm-up δ (deg) |Ω − Ω̂|", "angle (rad)")
    _lines(ax, lambda name: (t, columns[name]), ["x_0", "x_1"], "unit")
    ax.set_yscale("log")
    ax.axhline(0.5, color="r", ls="--", lw=0.8, label="limit")
    _save(fig, ax, io.BytesIO())


def _columns(c: Collection[str], spec: str | tuple[str, ...]) -> list[str]:
    """The columns a figure's ``spec`` names, per-unit prefixes expanded."""
    names = (spec,) if isinstance(spec, str) else spec
    out: list[str] = []
    for name in names:
        out += _units(c, name) if name.endswith("_") else [name]
    return out


def _drawn(header: Sequence[str]) -> list[str]:
    """The columns of ``header`` a figure of :func:`plot_run` draws, the time first."""
    named = set(header)
    return ["t", *(n for _, _, _, spec, _, _ in _FIGURES for n in _columns(named, spec) if n in named)]


def plot_run(run_dir: str | Path, processes: int = 1) -> dict[str, Path]:
    """Draw every figure the run's telemetry allows into ``run_dir/plots``; returns name → path.
    A missing or empty telemetry.csv is an :class:`InputFormatError` naming it, and so is a damaged
    summary.json (:func:`~hil.runtime.runlog.read_summary`). ``processes`` > 1 shares the figures among
    that many processes forked after the data is read (:mod:`hil.plots.forked`; while another thread of
    this process runs, they are all drawn here).

    A time gap between rows (:class:`~hil.plots.streamed.Gaps`) breaks the lines; a value beyond
    ±:data:`~hil.plots.streamed.PLOT_LIMIT` is left out, counted in its figure's title; a reading its line
    cannot show (alone between gaps: :func:`~hil.plots.series.lone_points`) is a dot, and a value ≤ 0 on a
    log scale a triangle at the axes' foot, counted in the title. Each figure is
    written beside its file and renamed over it (a link there is replaced, never written through); a
    ``plots`` that cannot be made is a ConfigError naming it, a figure the OS refuses an
    :class:`~hil.files.output.OutputError` naming its file."""
    run_dir = Path(run_dir)
    path = run_dir / "telemetry.csv"
    with TelemetryBlocks(path, columns=_drawn) as blocks:  # only what the figures draw, thinned as read
        drawn = blocks.names[1:]  # the time first
        stream = MinMaxStream(len(drawn))
        for block in blocks:
            stream.add(block[:, 0], block[:, 1:])
    if blocks.rows == 0:
        raise InputFormatError("no telemetry rows to plot", str(path))
    column = {name: j for j, name in enumerate(drawn)}

    def series(name: str) -> tuple[np.ndarray, np.ndarray]:
        return stream.series(column[name])

    peaks = stream.peak()
    summary = read_summary(run_dir)
    limit = _rate_limit(summary.get("max_gimbal_rate_limit") if summary else None)
    markers = run_markers(iter_events(run_dir / "events.jsonl"))  # streamed: only the markers kept
    out_dir = make_dir(run_dir / "plots")  # a file of that name: a ConfigError naming it

    def figure(name: str, title: str, ylabel: str, present: list[str], label: str, log: bool) -> Path:
        off = int(sum(int(stream.off_scale[column[n]]) for n in present))
        if off:
            title = f"{title} ({off} values beyond ±{PLOT_LIMIT:g} left out)"
        below = int(sum(int(stream.not_positive[column[n]]) for n in present)) if log else 0
        if below:
            title = f"{title} ({below} values ≤ 0: ▼)"
        fig, ax = _figure(title, ylabel)
        _lines(ax, series, present, label, log)
        if log:
            ax.set_yscale("log")
        peak = max((float(peaks[column[n]]) for n in present), default=math.nan)
        if name == "gimbal_rates" and limit is not None and math.isfinite(peak):
            if peak >= 0.25 * limit:  # the limit in view when the rates come near it
                for sign in (1, -1):
                    ax.axhline(sign * limit, color="r", ls="--", lw=0.8, label="limit" if sign > 0 else None)
            else:  # rates far below the limit: scaled to the data (a ±limit axis would flatten them)
                ax.set_title(f"{title} (peak {peak:.3g} rad/s, limit ±{limit:g} rad/s: off the scale)")
        draw_markers(ax, markers)
        return _save(fig, ax, out_dir / f"{name}.png")

    names: list[str] = []
    jobs: list[Callable[[], Path]] = []
    for name, title, ylabel, spec, label, log in _FIGURES:
        present = [n for n in _columns(column, spec) if n in column and stream.finite[column[n]]]
        if present:  # a column the run lacks, or never filled: no figure
            names.append(name)
            jobs.append(partial(figure, name, title, ylabel, present, label, log))
    return dict(zip(names, draw_shared(jobs, processes), strict=True))


def _rate_limit(value: object) -> float | None:
    """The summary's ``max_gimbal_rate_limit`` as the gimbal-rate figure's limit line: a finite number in
    (0, :data:`~hil.plots.streamed.PLOT_LIMIT`], else None (no line: -1e308 made matplotlib's transform
    singular)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return None
    return float(value) if math.isfinite(value) and 0 < value <= PLOT_LIMIT else None
