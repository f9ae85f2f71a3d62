"""The estimator's figures. With ground truth, the paper's two: the principal angle of the attitude
estimation error ``Q = R R̂ᵀ`` and the angular-velocity estimation error, against time (plus the heading /
inclination split). Without, the estimate itself: roll/pitch/yaw (ENU, z-y-x) and the body rates."""

from __future__ import annotations

from pathlib import Path
from typing import IO, TYPE_CHECKING, TypeVar

import numpy as np
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from hil.estimation.metrics import AttitudeErrors
from hil.files.output import replace_file
from hil.plots.series import break_wraps, envelope, lone_points, wrap_times

if TYPE_CHECKING:
    from hil.logs.replay import ReplayResult

Target = TypeVar("Target", Path, IO[bytes])


def _figure(title: str, ylabel: str) -> tuple[Figure, Axes]:
    """One 8 × 4 in axes with fixed margins (room for a title, the axis labels, 5-digit tick labels and,
    right of the axes, the legend, which so never covers data: a tight layout costs a second drawing of
    every figure)."""
    fig = Figure(figsize=(10, 4))
    fig.subplots_adjust(left=0.08, right=0.74, bottom=0.12, top=0.91)
    # The title at the axes' top, not placed anew at each draw: nothing is drawn above the axes, and the
    # automatic placement measured every tick label again (the same pixels; ~3 % of a figure's time).
    with rc_context({"axes.titley": 1.0}):
        ax = fig.add_subplot()
    ax.set_xlabel("time (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    return fig, ax


def _shade(ax: Axes, intervals: list[tuple[float, float]], t0: float) -> None:
    """Shade each interval (s) in which the magnetometer was left out as disturbed."""
    for i, (a, b) in enumerate(intervals):
        label = "magnetometer left out (disturbed)" if i == 0 else None
        ax.axvspan(a - t0, b - t0, color="tab:red", alpha=0.12, lw=0, label=label)


def _line(
    ax: Axes, t: np.ndarray, y: np.ndarray, label: str, period: float | None = None, **style: object
) -> None:
    """Draw ``y`` (N,) against ``t`` (N,) s: a long series as its bins' means with their min/max band
    (:func:`hil.plots.series.envelope`), an angle with ``period`` cut where it wraps around."""
    env = envelope(t, y, period=period)
    if env is None:
        if period is not None:
            t, y = wrap_times(t, y, period), break_wraps(y, period)
        (line,) = ax.plot(t, y, label=label, **style)  # type: ignore[arg-type]
        _dots(ax, t, y, line)
        return
    (line,) = ax.plot(env.t, env.mean, label=label, **style)  # type: ignore[arg-type]
    ax.fill_between(env.t, env.low, env.high, color=line.get_color(), alpha=0.25, lw=0)
    _dots(ax, env.t, env.mean, line)


def _dots(ax: Axes, t: np.ndarray, y: np.ndarray, line: Line2D) -> None:
    """The points of ``y`` (N,) against ``t`` (N,) s that ``line`` cannot show
    (:func:`~hil.plots.series.lone_points`: a reading alone between gaps, a stretch narrower than a pixel)
    as dots of its colour, unlabelled: a line joins two points, so one alone was measured but not seen."""
    lone = lone_points(t, y)
    if lone.any():
        ax.plot(
            t[lone], y[lone], ls="none", marker="o", ms=2.5, color=line.get_color(), alpha=line.get_alpha()
        )


def _save(fig: Figure, ax: Axes, path: Target) -> Target:
    """The legend right of the axes, then the PNG into ``path`` (a binary stream, or a file's path: written
    beside it and renamed over it, :func:`~hil.files.output.replace_file` — a link there is replaced, never
    written through; a refusal an :class:`~hil.files.output.OutputError` naming the file)."""
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small")
    FigureCanvasAgg(fig)
    if isinstance(path, Path):
        replace_file(path, lambda f: fig.savefig(f, dpi=110, format="png"))
    else:
        fig.savefig(path, dpi=110, format="png")
    return path


def plot_attitude_error(
    t: np.ndarray,
    errors: AttitudeErrors,
    path: Path,
    title: str = "",
    rejected: list[tuple[float, float]] | None = None,
    t0: float = 0.0,
) -> Path:
    """Principal angle of the attitude estimation error (deg) against time, heading/inclination beside;
    the ``rejected`` intervals (s, on the clock ``t`` is on less ``t0``) shaded."""
    fig, ax = _figure(title or "Attitude estimation error", "attitude estimation error (deg)")
    _shade(ax, rejected or [], t0)
    _line(ax, t, errors.total, "principal angle of Q = R R̂ᵀ", lw=1.0)
    _line(ax, t, errors.heading, "heading part", lw=0.6, alpha=0.7)
    _line(ax, t, errors.inclination, "inclination part", lw=0.6, alpha=0.7)
    return _save(fig, ax, path)


def plot_rate_error(t: np.ndarray, error: np.ndarray, path: Path, title: str = "") -> Path:
    """Angular-velocity estimation error Ω − Ω̂ (rad/s), components and norm, against time."""
    fig, ax = _figure(
        title or "Angular velocity estimation error", "angular velocity estimation error (rad/s)"
    )
    for i, axis in enumerate("xyz"):
        _line(ax, t, error[:, i], axis, lw=0.6)
    _line(ax, t, np.linalg.norm(error, axis=1), "norm", color="k", lw=0.8)
    return _save(fig, ax, path)


def euler_zyx_deg(r: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (deg) of body → ENU rotations (N, 3, 3), z-y-x convention."""
    roll = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    pitch = -np.arcsin(np.clip(r[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    return np.degrees(np.column_stack([roll, pitch, yaw]))


def plot_attitude(
    t: np.ndarray,
    r: np.ndarray,
    path: Path,
    title: str = "",
    rejected: list[tuple[float, float]] | None = None,
    t0: float = 0.0,
    yaw_label: str = "yaw",
) -> Path:
    """The attitude estimate as roll, pitch, yaw (deg, ENU, z-y-x) against time; the ``rejected``
    intervals shaded (as :func:`plot_attitude_error`)."""
    fig, ax = _figure(title or "Attitude estimate", "attitude estimate (deg, ENU, z-y-x)")
    _shade(ax, rejected or [], t0)
    for series, label in zip(euler_zyx_deg(r).T, ("roll", "pitch", yaw_label), strict=True):
        _line(ax, t, series, label, period=360.0, lw=0.8)  # roll and yaw wrap at ±180°
    return _save(fig, ax, path)


def plot_rates(t: np.ndarray, omega: np.ndarray, path: Path, title: str = "") -> Path:
    """The body rate estimate Ω̂ (rad/s) against time."""
    fig, ax = _figure(title or "Angular velocity estimate", "body rate estimate (rad/s)")
    for i, axis in enumerate("xyz"):
        _line(ax, t, omega[:, i], f"Ω̂{axis}", lw=0.6)
    return _save(fig, ax, path)


def _apart(
    t: np.ndarray, values: np.ndarray, spans: list[tuple[float, float]]
) -> tuple[np.ndarray, np.ndarray]:
    """``t`` (N,) and ``values`` (N, …) with a NaN row put before the first estimate of each replayed part
    (``spans``, :attr:`~hil.logs.replay.ReplayResult.replayed_spans`) after the first: the lines are cut
    between parts. Drawn joined, a gap in the log (or a part not replayed) showed as a straight line of
    estimates the filter never made."""
    at = np.searchsorted(t, [first for first, _ in spans[1:]])
    return np.insert(t, at, t[at]), np.insert(values, at, np.nan, axis=0)


def _only_replayed(values: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """``values`` (N, …) with NaN where ``inside`` (N,) is False (a time no replayed part covers)."""
    return np.where(inside.reshape(-1, *([1] * (values.ndim - 1))), values, np.nan)


def plot_replay(result: ReplayResult, out_dir: Path) -> dict[str, Path]:
    """The figures for one replay; returns ``{name: path}``. Lines are drawn within the parts of the log
    replayed only (a log split at its gaps: docs/formats.md, "Gaps"), never across from one to the next."""
    est = result.estimates
    spans = result.replayed_spans
    name = Path(result.log.source).name
    rejected = result.mag_rejections
    six = result.log.six_axis  # no magnetometer: the yaw is the gyroscope's integral, drifting
    title = f"Attitude estimate — {name}" + (" (6-axis: heading unobserved)" if six else "")
    yaw = "yaw (unobserved: gyroscope only, drifts)" if six else "yaw"
    t_r, r = _apart(est.t, est.R, spans)
    t_w, omega = _apart(est.t, est.omega, spans)
    files = {
        "attitude": plot_attitude(t_r, r, out_dir / "attitude.png", title, rejected, yaw_label=yaw),
        "rates": plot_rates(t_w, omega, out_dir / "rates.png", f"Angular velocity estimate — {name}"),
    }
    c = result.comparison
    if c is None:
        return files
    inside = result.replayed(c.t)
    errors = AttitudeErrors(
        *(_only_replayed(e, inside) for e in (c.errors.total, c.errors.heading, c.errors.inclination))
    )
    files["attitude_error"] = plot_attitude_error(
        c.t, errors, out_dir / "attitude_error.png", f"Attitude estimation error — {name}", rejected
    )
    rate_error = _only_replayed(c.rate_error, result.replayed(c.rate_t))
    files["rate_error"] = plot_rate_error(
        c.rate_t, rate_error, out_dir / "rate_error.png", f"Angular velocity estimation error — {name}"
    )
    return files
