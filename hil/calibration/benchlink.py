"""The calibration tools' hold on a board: time passing on the client's clock, the telemetry it sends,
the modes the tools put it in, and the guards that stop a bench run.

A :class:`BenchLink` wraps a connected :class:`~hil.link.board.BoardClient` (lockstep through ``emu://``,
or real time on any port). :meth:`BenchLink.wait` lets time pass while the client keeps the session
alive; every ``Telemetry``, ``Log`` and ``EscCalibrationStatus`` that arrives meanwhile is kept for the
caller (:attr:`BenchLink.telemetry`, :meth:`BenchLink.take_statuses`). :class:`Guard` stops a sweep
when the battery current exceeds its limit or the pack sags below its floor (:class:`GuardTripped`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from hil.link.board import (
    BoardClient,
    BoardResetEvent,
    EscCalibrationEvent,
    LinkLostEvent,
    LogEvent,
    TelemetryEvent,
)
from protocol.errors import ConfigError, LinkError, ProtocolError
from protocol.messages import (
    ActuatorSetpoint,
    BoardState,
    ControlMode,
    EscCalibrationStatus,
    GimbalMode,
    Log,
    PowerState,
    RawPulses,
    Telemetry,
    UnitSetpoint,
)

TICK_S = 0.02
"""How often the tools look at what arrived and re-send their pulses (s)."""


class GuardTripped(ProtocolError):
    """A bench guard stopped the run (battery current or voltage); the outputs are already safe."""


class BoardLost(LinkError):
    """The board reset, or its link was lost, while a bench step was under way: what the step was doing
    (an ESC being taught, a sweep's step, a verification point) did not happen on the board it started on."""


def describe_fault(event: BoardResetEvent | LinkLostEvent) -> str:
    """One line for a link fault: ``the board reset (POWER_ON: ...)`` or ``the board link was lost (...)``."""
    if isinstance(event, BoardResetEvent):
        return f"the board reset ({event.cause.name}: {event.evidence})"
    return f"the board link was lost ({event.reason})"


@dataclass(frozen=True)
class Guard:
    """Stop when the pack current exceeds ``max_current_a`` (A) or its voltage falls below
    ``min_battery_v`` (V; None: no floor), as the board's telemetry reports them."""

    max_current_a: float = 8.0
    min_battery_v: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_current_a) and self.max_current_a > 0):
            raise ConfigError(f"{self.max_current_a!r} must be a positive number of amps", "--max-current")
        if self.min_battery_v is not None and not (
            math.isfinite(self.min_battery_v) and self.min_battery_v >= 0
        ):
            raise ConfigError(f"{self.min_battery_v!r} must be a voltage >= 0", "--min-battery")

    def check(self, tel: Telemetry) -> str | None:
        """Why ``tel`` trips the guard, or None: the pack's current or voltage beyond the limits, or the
        board's power manager shedding the rotors (SHED, BROWN_OUT) — a sweep then waited out its settling
        for pulses that never came and ended "no telemetry while holding the command"."""
        amps, volts = tel.battery_ma / 1000.0, tel.battery_mv / 1000.0
        if tel.power >= PowerState.SHED:
            return f"the board shed the rotors (power {PowerState(tel.power).name}, battery {volts:.2f} V)"
        if amps > self.max_current_a:
            return f"battery current {amps:.2f} A over the limit {self.max_current_a:g} A"
        if self.min_battery_v is not None and volts < self.min_battery_v:
            return f"battery {volts:.2f} V under the floor {self.min_battery_v:g} V"
        return None


class BenchLink:
    """A connected board as the calibration tools use it. ``unit`` is checked against the board."""

    def __init__(self, client: BoardClient) -> None:
        info = client.info
        if info is None:
            raise LinkError("the board client is not connected (call connect() first)")
        self.client = client
        self.info = info
        self.telemetry: list[Telemetry] = []  # every Telemetry since the last clear_telemetry()
        self.logs: list[Log] = []
        self._statuses: list[EscCalibrationStatus] = []
        self.base_widths: tuple[int, ...] | None = None  # the board's disarmed outputs, for RawPulses
        self.faults: list[BoardResetEvent | LinkLostEvent] = []  # resets and link losses, in order
        self._faults_seen = 0  # how many of them check_board() has raised already
        self.touched = False  # a command that moves the outputs went out (prepare, an ESC procedure)

    def check_unit(self, unit: int) -> None:
        if isinstance(unit, bool) or not isinstance(unit, int) or not 0 <= unit < self.info.n_units:
            raise ConfigError(f"{unit!r}: the board has units 0..{self.info.n_units - 1}", "--unit")

    # ------------------------------------------------------------------ time
    @property
    def now(self) -> float:
        return self.client.clock.now()

    def wait(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Let ``seconds`` pass (or stop early once ``until()`` holds: True), collecting what arrives."""
        done = until if until is not None else (lambda: False)

        def check() -> bool:
            self._collect()
            return done()

        hit = self.client.wait_for(check, seconds)
        self._collect()
        return hit

    def _collect(self) -> None:
        for event in self.client.drain_events():
            if isinstance(event, TelemetryEvent):
                self.telemetry.append(event.telemetry)
            elif isinstance(event, LogEvent):
                self.logs.append(event.log)
            elif isinstance(event, EscCalibrationEvent):
                self._statuses.append(event.status)
            elif isinstance(event, BoardResetEvent | LinkLostEvent):
                self.faults.append(event)

    def check_board(self, during: str) -> None:
        """Raise :class:`BoardLost` for the first reset or link loss not raised yet, saying it happened
        ``during`` (e.g. ``"the rotor sweep, at 1250 us"``). Each fault is raised once: a caller that puts
        the board back to rest afterwards is not stopped by the same fault again."""
        if self._faults_seen < len(self.faults):
            event = self.faults[self._faults_seen]
            self._faults_seen = len(self.faults)
            raise BoardLost(f"{describe_fault(event)} during {during}")

    def clear_telemetry(self) -> None:
        self.telemetry.clear()

    def latest(self, where: Callable[[Telemetry], bool] = lambda t: True, timeout: float = 2.0) -> Telemetry:
        """The next Telemetry to arrive for which ``where`` holds (telemetry sent before a command took
        effect may still be on its way); LinkError if none comes within ``timeout`` s."""
        self.clear_telemetry()
        if not self.wait(timeout, lambda: any(where(t) for t in self.telemetry)):
            raise LinkError(f"no such telemetry from the board within {timeout} s")
        return [t for t in self.telemetry if where(t)][-1]

    def take_statuses(self) -> list[EscCalibrationStatus]:
        out, self._statuses = self._statuses, []
        return out

    # ------------------------------------------------------------------ modes
    def prepare(self, mode: ControlMode, gimbal_mode: GimbalMode) -> Telemetry:
        """Leave the board DISARMED in ``mode`` with its gimbals read as ``gimbal_mode``: the emulators and
        the firmware's estimates read a gimbal pulse as a rate or an angle by the last setpoint's mode, so
        the board is armed for one setpoint of that mode that moves nothing (gimbals held where they are,
        rotors at zero). Returns the disarmed telemetry, whose pulses become the base widths of
        :meth:`raw` (rotors at the safe pulse, gimbals holding)."""
        client = self.client
        self.touched = True
        client.disarm()
        client.set_mode(ControlMode.SETPOINT)
        tel = self.latest(lambda t: t.state is BoardState.DISARMED)
        angle = gimbal_mode is GimbalMode.ANGLE
        hold = tuple(UnitSetpoint(u.gimbal_angle if angle else 0.0, 0.0) for u in tel.units)
        client.arm()
        self.setpoint(gimbal_mode, hold)
        self.wait(3 * TICK_S)
        client.disarm()
        if mode is not ControlMode.SETPOINT:
            client.set_mode(mode)
        tel = self.latest(lambda t: t.state is BoardState.DISARMED and t.mode is mode)
        if 0 in tel.pulses_us[1::2]:
            raise ProtocolError(f"the board has rotor channels without pulses {tel.pulses_us}: not ready")
        self.base_widths = tuple(tel.pulses_us)
        return tel

    def raw(self, widths: dict[int, int]) -> None:
        """RawPulses: the base widths with ``widths`` (channel → µs) replaced."""
        if self.base_widths is None:
            raise ProtocolError("prepare(RAW_PULSES, ...) first")
        out = list(self.base_widths)
        for ch, w in widths.items():
            out[ch] = int(round(w))
        self.client.send_setpoint(RawPulses(pulses_us=tuple(out)))

    def setpoint(self, gimbal_mode: GimbalMode, units: Sequence[UnitSetpoint]) -> None:
        self.client.send_setpoint(ActuatorSetpoint(gimbal_mode=gimbal_mode, units=tuple(units)))

    def safe(self) -> None:
        """Everything back to rest: base pulses if raw, then Disarm and SETPOINT mode (best effort on a
        link that is still up; the board's link watchdog covers the rest)."""
        client = self.client
        if not client.connected:
            return
        if self.base_widths is not None and client.state is BoardState.ARMED:
            self.raw({})
        client.disarm()
        client.set_mode(ControlMode.SETPOINT)


MAX_HOLD_S = 600.0
"""The longest (s) a step may settle, be watched or dwell: a rotor spins up and a gimbal turns in seconds,
and a step held for 1e160 s never ended (its dwell's telemetry kept in memory all the while)."""


def check_tolerance(value: float, option: str) -> None:
    """A settling or verification tolerance: a finite number > 0 in its column's unit, or
    :class:`ConfigError` naming ``option`` (a negative one left every step unsettled, NaN every step
    settled: comparisons with NaN are false)."""
    if not (math.isfinite(value) and value > 0):
        raise ConfigError(f"{value!r} must be a finite number > 0", option)


@dataclass(frozen=True)
class Settling:
    """How long a held command is watched (s): at least ``settle_s``; settled once every watched value
    stays within its tolerance over ``window_s``; given up after ``max_s`` (the result says unsettled);
    then ``dwell_s`` of telemetry is averaged. Each at most :data:`MAX_HOLD_S`."""

    settle_s: float = 0.3
    window_s: float = 0.5
    max_s: float = 10.0
    dwell_s: float = 0.25

    def __post_init__(self) -> None:
        for name in ("settle_s", "window_s", "max_s", "dwell_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 < value <= MAX_HOLD_S):
                what = f"{value!r} must be a positive number of seconds, at most {MAX_HOLD_S:g}"
                raise ConfigError(what, f"Settling.{name}")
        if self.max_s < self.settle_s:
            raise ConfigError(
                f"{self.max_s!r} must be at least the settle time, {self.settle_s!r}", "Settling.max_s"
            )


def hold(
    link: BenchLink,
    send: Callable[[], None],
    ready: Callable[[Telemetry], bool],
    watched: Callable[[Telemetry], Sequence[float]],
    tolerance: Callable[[int, float], float],
    settling: Settling,
    check: Callable[[], None],
) -> tuple[list[Telemetry], bool]:
    """Hold a command (``send`` re-sends it every 0.1 s) until the board's telemetry shows it
    (``ready``) and the ``watched`` values settle (value ``i`` within ``tolerance(i, value)`` over the
    window), then collect the dwell. ``check()`` runs after every wait (the guards). Returns the dwell's
    telemetry and whether it settled. :class:`ProtocolError` if the board never shows the command."""
    samples: list[tuple[float, Telemetry]] = []
    t0 = link.now
    since: float | None = None
    settled = False
    resend = 0
    while True:
        if resend <= 0:
            send()
            resend = 5
        resend -= 1
        link.clear_telemetry()
        link.wait(TICK_S)
        check()
        now = link.now
        for tel in link.telemetry:
            if ready(tel):
                since = now if since is None else since
                samples.append((now, tel))
        if since is None:
            if now - t0 > settling.max_s:
                raise ProtocolError("the board's telemetry never showed the command")
            continue
        window = [watched(tel) for t, tel in samples if t >= now - settling.window_s]
        if now - since >= settling.settle_s and len(window) >= 2 and _steady(window, tolerance):
            settled = True
            break
        if now - since >= settling.max_s:
            break
    dwell: list[Telemetry] = []
    end = link.now + settling.dwell_s
    while link.now < end or not dwell:
        link.clear_telemetry()
        link.wait(TICK_S)
        check()
        dwell += [tel for tel in link.telemetry if ready(tel)]
        if link.now - end > settling.max_s:
            raise ProtocolError("no telemetry while holding the command")
    return dwell, settled


def _steady(window: list[Sequence[float]], tolerance: Callable[[int, float], float]) -> bool:
    for i in range(len(window[0])):
        values = [w[i] for w in window]
        if max(values) - min(values) > tolerance(i, values[-1]):
            return False
    return True
