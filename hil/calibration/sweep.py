"""Bench sweeps: step one channel's pulse width over its range and record what the unit does.

:func:`run_sweep` puts the board in RAW_PULSES mode (every other rotor at the safe pulse, every other
gimbal holding), arms it, and steps the rotor or gimbal channel of one unit from ``start_us`` to
``stop_us`` and back (:class:`SweepPlan`), moving between steps no faster than ``rate_limit_us_s``. At
each step it waits until the board's telemetry shows the width and the measured response has settled
(:class:`~hil.calibration.benchlink.Settling`: it stays within ``tolerance`` over a window, after a
minimum time; at most a maximum time, else the row is marked unsettled), then averages the dwell's
telemetry: rotor speed,
gimbal rate or gimbal angle, battery voltage and current. Every telemetry sample passes the
:class:`~hil.calibration.benchlink.Guard`: over the current limit (or under the battery floor) the sweep
stops at once, the outputs go back to rest, and the result says why (``stopped``).

:meth:`SweepResult.write_csv` writes the bench CSV ``hil calibrate fit`` reads (``pulse_us``,
``battery_v``, the measurement, and the extra columns ``battery_a``, ``direction``, ``samples``,
``settled``, ``board_time_s``) with ``#`` metadata lines: board identity, port, unit and channel, date,
battery state at the start and the end, the plan, and its status: ``# status: complete``, or ``# status:
partial: <why>; <n> of <m> steps`` for a sweep stopped by the guard, interrupted, failed, or still running
(:func:`run_sweep` keeps the file up to date after every step; see :mod:`.bench` for what readers do).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from protocol.errors import ConfigError, HilError, ProtocolError
from protocol.messages import BoardState, ControlMode, GimbalMode, Telemetry

from .bench import STATUS_KEY, BenchKind, read_bench_csv, write_bench_csv
from .benchlink import TICK_S, BenchLink, Guard, GuardTripped, Settling, check_tolerance, hold
from .progress import Eta, Report, duration, no_report
from .textfiles import check_writable


@dataclass(frozen=True)
class Measure:
    """How a sweep of ``kind`` reads its unit: the CSV column, the ``UnitState`` field, the channel
    (0: gimbal, 1: rotor), how the board must read gimbal pulses, the default step (µs) and settling
    tolerance (in the column's unit, plus ``rel`` of the value)."""

    column: str
    field: str
    offset: int
    gimbal_mode: GimbalMode
    step_us: int
    tolerance: float
    rel: float = 0.0


MEASURES = {
    BenchKind.ROTOR: Measure("rotor_speed_rad_s", "rotor_speed", 1, GimbalMode.RATE, 40, 0.3, 0.0005),
    BenchKind.GIMBAL_RATE: Measure("gimbal_rate_rad_s", "gimbal_rate", 0, GimbalMode.RATE, 20, 0.004),
    BenchKind.GIMBAL_ANGLE: Measure("gimbal_angle_rad", "gimbal_angle", 0, GimbalMode.ANGLE, 25, 0.002),
}


MIN_RATE_LIMIT_US_S = 1.0
"""The slowest a sweep may move its pulse (µs/s): the whole 500–2500 µs span in at most 2 000 s (at
1e-300 µs/s the pulse never reached its first step)."""


@dataclass(frozen=True)
class SweepPlan:
    """One sweep (pulses in µs, times in s). ``step_us``/``tolerance`` None: the kind's default."""

    kind: BenchKind
    start_us: int = 1000
    stop_us: int = 2000
    step_us: int | None = None
    directions: str = "both"  # "up", "down" or "both" (up, then back down)
    settling: Settling = field(default_factory=Settling)
    rate_limit_us_s: float = 2000.0
    tolerance: float | None = None
    guard: Guard = field(default_factory=Guard)

    def __post_init__(self) -> None:
        if not 500 <= self.start_us < self.stop_us <= 2500:
            raise ConfigError(
                f"{self.start_us}..{self.stop_us} µs; need 500 <= start < stop <= 2500", "--range"
            )
        if self.step_us is not None and not 1 <= self.step_us <= self.stop_us - self.start_us:
            raise ConfigError(f"{self.step_us} µs does not fit the range", "--step")
        if self.directions not in ("up", "down", "both"):
            raise ConfigError(f"{self.directions!r}; need up, down or both", "--directions")
        if not (math.isfinite(self.rate_limit_us_s) and self.rate_limit_us_s >= MIN_RATE_LIMIT_US_S):
            raise ConfigError(
                f"{self.rate_limit_us_s!r} must be a finite number of µs/s, at least {MIN_RATE_LIMIT_US_S:g}",
                "--rate-limit",
            )
        if self.tolerance is not None:
            check_tolerance(self.tolerance, "--tolerance")

    @property
    def measure(self) -> Measure:
        return MEASURES[self.kind]

    def pulses(self) -> list[tuple[int, str]]:
        """(width µs, "up" | "down") in sweep order; both ends always included."""
        step = self.step_us or self.measure.step_us
        up = list(range(self.start_us, self.stop_us, step)) + [self.stop_us]
        if self.directions == "up":
            return [(p, "up") for p in up]
        down = [(p, "down") for p in reversed(up)]
        return down if self.directions == "down" else [(p, "up") for p in up] + down[1:]

    def describe(self) -> str:
        step = self.step_us or self.measure.step_us
        s = self.settling
        return (
            f"{self.start_us}-{self.stop_us} us in {step} us steps ({self.directions}), settle "
            f"{s.settle_s:g}-{s.max_s:g} s (window {s.window_s:g} s), dwell {s.dwell_s:g} s, at most "
            f"{self.rate_limit_us_s:g} us/s; guard {self.guard.max_current_a:g} A"
            + ("" if self.guard.min_battery_v is None else f", {self.guard.min_battery_v:g} V")
        )


@dataclass(frozen=True)
class SweepRow:
    """One step, averaged over its dwell: the width (µs), the measurement (rad/s or rad), the pack's
    voltage (V) and current (A), how many telemetry samples, whether it settled, board uptime (s)."""

    pulse_us: int
    direction: str
    value: float
    battery_v: float
    battery_a: float
    samples: int
    settled: bool
    board_time_s: float


@dataclass(frozen=True)
class SweepResult:
    """A sweep's rows and where they came from; ``stopped`` says why it ended early (None: complete)."""

    unit: int
    plan: SweepPlan
    rows: tuple[SweepRow, ...]
    metadata: tuple[str, ...]
    stopped: str | None = None
    planned: int = 0
    """Steps the plan has (``len(plan.pulses())``)."""

    def status(self, partial: bool) -> str:
        """The file's status comment: ``complete``, or ``partial: <why>`` (bench.py reads it)."""
        if not partial:
            return "complete"
        why = (
            f"stopped early: {self.stopped}" if self.stopped else "in progress (a file left so was cut short)"
        )
        return f"partial: {why}; {len(self.rows)} of {self.planned} steps"

    def write_csv(self, path: str | os.PathLike[str], partial: bool | None = None) -> Path:
        """The bench CSV of this sweep (see the module docstring), marked partial if ``partial`` (None:
        if it stopped early)."""
        m = self.plan.measure
        columns = [
            "pulse_us",
            "battery_v",
            m.column,
            "battery_a",
            "direction",
            "samples",
            "settled",
            "board_time_s",
        ]
        rows: list[tuple[str, ...]] = [
            (
                str(r.pulse_us),
                f"{r.battery_v:.3f}",
                f"{r.value:.5g}",
                f"{r.battery_a:.3f}",
                r.direction,
                str(r.samples),
                "1" if r.settled else "0",
                f"{r.board_time_s:.3f}",
            )
            for r in self.rows
        ]
        status = self.status(self.stopped is not None if partial is None else partial)
        return write_bench_csv(path, columns, rows, [*self.metadata, f"{STATUS_KEY} {status}"])


def run_sweep(
    link: BenchLink,
    units: Sequence[int],
    plan: SweepPlan,
    *,
    paths: Mapping[int, str | os.PathLike[str]] | None = None,
    report: Report = no_report,
) -> dict[int, SweepResult]:
    """Sweep the channel of each of ``units`` together (see the module docstring; the channels are
    independent, the guard sees their sum), one result per unit. A tripped guard ends the sweep early
    with ``stopped`` set; a board that leaves ARMED (link watchdog, reset) raises :class:`ProtocolError`;
    an interrupt (Ctrl-C, SIGTERM) is raised on. Whichever way it ends the outputs are put back to rest
    (raw base widths, Disarm, SETPOINT mode) first.

    ``paths`` (unit → file): each unit's bench CSV is rewritten after every step, marked
    ``# status: partial`` until the sweep completes, so a sweep cut short (interrupted, stopped by the
    guard, the board lost, the host killed) leaves what it measured, marked as such. ``report`` gets one
    line per step with the time left."""
    if not units or len(set(units)) != len(units):
        raise ConfigError(f"{list(units)}: give each unit once", "--unit")
    for unit in units:
        link.check_unit(unit)
    if paths is not None:  # a CSV that cannot be written is refused before the board is armed
        for unit in units:
            check_writable(paths[unit])
    m = plan.measure
    channels = {unit: 2 * unit + m.offset for unit in units}
    pulses = plan.pulses()
    started = datetime.now(UTC).isoformat(timespec="seconds")
    if paths is not None:  # a sweep starts over: what it will replace is said before it does
        for unit in units:
            there = on_disk(paths[unit])
            if there is not None:
                report(
                    f"unit {unit}: {paths[unit]} holds {there}: this sweep starts over (it does not resume) "
                    "and replaces it from its first measured step"
                )
    link.check_board(f"the time before the {plan.kind.value} sweep")  # a board that reset since: say so
    first = link.prepare(ControlMode.RAW_PULSES, m.gimbal_mode)
    assert link.base_widths is not None
    rows: dict[int, list[SweepRow]] = {unit: [] for unit in units}
    eta = Eta(len(pulses))

    def results(stopped: str | None, last: Telemetry | None) -> dict[int, SweepResult]:
        meta = _metadata(link, plan, units, channels, started, first, last)
        return {
            unit: SweepResult(unit, plan, tuple(rows[unit]), tuple(meta[unit]), stopped, len(pulses))
            for unit in units
        }

    def keep(stopped: str | None, last: Telemetry | None, partial: bool) -> dict[int, SweepResult]:
        out = results(stopped, last)
        if paths is not None and rows[units[0]]:  # the units' steps are measured together
            for unit, result in out.items():
                result.write_csv(paths[unit], partial=partial)
        return out

    stopped = None
    try:
        link.client.arm()
        width = link.base_widths[channels[units[0]]]
        for target, direction in pulses:
            width = _ramp(link, plan, list(channels.values()), width, target)
            for unit, row in _measure(link, plan, channels, target, direction).items():
                rows[unit].append(row)
            eta.step()
            report(_step_line(plan, rows, eta))
            keep(None, None, partial=True)
    except GuardTripped as exc:
        stopped = str(exc)
    except BaseException as exc:  # interrupted, the board lost: kept as measured, marked, raised on
        why = f"interrupted ({exc or 'SIGINT'})" if isinstance(exc, KeyboardInterrupt) else f"failed: {exc}"
        try:
            link.safe()
        except HilError as unsafe:  # the caller's own attempt (hil calibrate's) reports the board's state
            report(f"could not put the outputs back to rest: {unsafe}")
        finally:
            kept = keep(why, None, partial=True)
            if paths is not None:
                for unit, result in kept.items():
                    if not result.rows:
                        report(f"unit {unit}: no step measured: {not_written(paths[unit])}")
                        continue
                    report(
                        f"unit {unit}: partial bench CSV kept, {len(result.rows)} of {len(pulses)} steps, "
                        f"marked '# status: partial' -> {paths[unit]}"
                    )
        raise
    link.safe()
    return keep(stopped, link.latest(), partial=stopped is not None)


def on_disk(path: str | os.PathLike[str]) -> str | None:
    """What the bench CSV at ``path`` holds, in words (None: no file there), for a sweep about to replace
    it: a complete sweep, a partial one and why, or a file that is no bench CSV."""
    if not os.path.lexists(path):
        return None
    try:
        data = read_bench_csv(path)
    except HilError as exc:
        return f"a file that is no bench CSV ({exc})"
    if data.partial is not None:
        return f"a partial sweep of {len(data)} rows ({data.partial.split(': ', 1)[-1]})"
    return f"a complete sweep of {len(data)} rows"


def not_written(path: str | os.PathLike[str]) -> str:
    """A sweep that measured no step writes no bench CSV: the words for what is left at ``path``. A
    header-only partial file replaced a whole earlier sweep there (which no fit can read)."""
    there = on_disk(path)
    return f"no bench CSV written; {path} is left as it was ({there})" if there else "no bench CSV written"


def _step_line(plan: SweepPlan, rows: Mapping[int, list[SweepRow]], eta: Eta) -> str:
    """``rotor sweep 12/51, 1440 us up: unit 0 523.1 rad/s; 25 s elapsed, about 1 min 20 s left``."""
    unit_of = "rad" if plan.kind is BenchKind.GIMBAL_ANGLE else "rad/s"
    values = ", ".join(
        f"unit {unit} {r[-1].value:.4g} {unit_of}{'' if r[-1].settled else ' (unsettled)'}"
        for unit, r in rows.items()
    )
    row = next(iter(rows.values()))[-1]
    return (
        f"{plan.kind.value} sweep {eta.done}/{eta.total}, {row.pulse_us} us {row.direction}: {values}; "
        f"{duration(eta.elapsed_s)} elapsed, "
        + ("done" if eta.done >= eta.total else f"about {duration(eta.left_s)} left")
    )


def _metadata(
    link: BenchLink,
    plan: SweepPlan,
    units: Sequence[int],
    channels: Mapping[int, int],
    started: str,
    first: Telemetry,
    last: Telemetry | None,
) -> dict[int, list[str]]:
    end = "(the sweep did not end)" if last is None else _battery(last)
    return {
        unit: [
            f"vscmg-hil bench sweep: {plan.kind.value} of unit {unit} (channel {channel}), hil calibrate",
            f"board: {link.info.describe()}",
            f"port: {link.client.transport.url}",
            f"date: {started} (host clock, UTC)",
            f"battery at start: {_battery(first)}; at end: {end}",
            f"plan: {plan.describe()}"
            + (f"; swept together with units {list(units)}" if len(units) > 1 else ""),
        ]
        for unit, channel in channels.items()
    }


def _battery(tel: Telemetry) -> str:
    return f"{tel.battery_mv / 1000:.2f} V, {tel.battery_ma / 1000:.2f} A, {tel.battery_soc} %"


def _check(link: BenchLink, plan: SweepPlan, width: int) -> None:
    """Every telemetry sample collected so far against the guard and the board's state; a reset or a
    lost link first (:class:`~hil.calibration.benchlink.BoardLost`: said as such, at once, rather than as
    the state the restarted board reports, or as a step whose telemetry never came)."""
    link.check_board(f"the {plan.kind.value} sweep, at {width} us")
    for tel in link.telemetry:
        why = plan.guard.check(tel)
        if why is not None:
            raise GuardTripped(f"{why} at {width} us")
        if tel.state is not BoardState.ARMED:
            raise ProtocolError(f"the board left ARMED ({tel.state.name}) during the sweep, at {width} us")


def _ramp(link: BenchLink, plan: SweepPlan, channels: list[int], width: int, target: int) -> int:
    """Move ``channels`` from ``width`` to ``target`` no faster than the plan's rate limit."""
    step = plan.rate_limit_us_s * TICK_S
    while width != target:
        width = (
            target if abs(target - width) <= step else int(round(width + math.copysign(step, target - width)))
        )
        link.clear_telemetry()
        link.raw(dict.fromkeys(channels, width))
        link.wait(TICK_S)
        _check(link, plan, width)
    return width


def _measure(
    link: BenchLink, plan: SweepPlan, channels: dict[int, int], target: int, direction: str
) -> dict[int, SweepRow]:
    """Hold ``target`` on every channel until every unit's response settles, then average the dwell."""
    m = plan.measure
    raw = dict.fromkeys(channels.values(), target)
    units = list(channels)
    base_tol = plan.tolerance if plan.tolerance is not None else m.tolerance
    dwell, settled = hold(
        link,
        send=lambda: link.raw(raw),
        ready=lambda tel: all(tel.pulses_us[ch] == target for ch in raw),
        watched=lambda tel: [_value(tel, m, unit) for unit in units],
        tolerance=lambda i, value: base_tol + m.rel * abs(value),
        settling=plan.settling,
        check=lambda: _check(link, plan, target),
    )
    n = len(dwell)
    volts = sum(t.battery_mv for t in dwell) / n / 1000.0
    amps = sum(t.battery_ma for t in dwell) / n / 1000.0
    return {
        unit: SweepRow(
            pulse_us=target,
            direction=direction,
            value=sum(_value(t, m, unit) for t in dwell) / n,
            battery_v=volts,
            battery_a=amps,
            samples=n,
            settled=settled,
            board_time_s=dwell[-1].time_ms / 1000.0,
        )
        for unit in units
    }


def _value(tel: Telemetry, m: Measure, unit: int) -> float:
    return float(getattr(tel.units[unit], m.field))
