"""The world on the far side of the board, for closed-loop emulation: the board's pulses drive the ESCs
and gimbal servos of a spacecraft with VSCMGs, and a phone on the spacecraft senses its motion.

The world reads the widths the board's timers put out (``Board.outputs``) and turns each into what the
motor driver makes of it through the unit's calibration map — the rotor ESC's steady speed at the present
battery voltage, the gimbal servo's rate (or angle) — and lets the drives of
:class:`.models.ServoModel` drive the plant (:class:`.models.Plant`) towards it. A channel
without pulses (board booting, outputs off, a dead ESC) has no drive: the gimbal holds, the rotor coasts
down against its drag (the motor's coasting time constant, as the board's own unit model has it).

**Batches.** Those widths change only at the pulse frames (unless the MCU resets, a channel dies or the
gimbal mode changes: ``Board.drive_epoch``), so the world steps the plant *ahead* in one compiled batch to
the board's next frame (:class:`.models.CompiledPlant` with the drive law inside its integrator stages,
keeping every state; the scenario's ``plant_step_s`` ≤ 1 ms per step) and the phone senses along it
(:meth:`.models.BodyPhone.sample_path_intervals`). The world then moves through those steps as
the caller's time passes: at each board event the unit states of the step it falls in go to the board
(``Board.hand_over``, plain floats: its telemetry, power draw and dead-ESC detection follow the physics
at the board's own rates), the board runs what is due, and the phone's samples are handed out up to the
present.
An event that changes what the drives see drops the steps ahead (the phone's noise stream is rewound with
them) and the drives take the new widths there — what a step-by-step loop would do, with the board's
events at the same plant steps. ``World(..., compiled=False)`` runs the same schedule on the numpy
:class:`.models.Plant` and :meth:`BodyPhone.sample`, one step at a time (the reference; the same samples
and truth to rounding).

The world keeps the board's time: it is advanced to the board clock's present by :meth:`World.advance_to`
(the lockstep runtime calls it from its plant task; ``firmware-sim --world`` from its serving loop) and
returns the phone samples taken meanwhile. The truth (attitude, rate) is there for logs and metrics.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from hil.control.motor_loops import Setpoints
from hil.estimation.sensors import SensorSample
from hil.threads import ThreadError
from hil.vscmg import PlantState
from protocol.messages import GimbalMode, UnitState

from ..board.actuators import UnitModel
from ..board.config import BoardConfig
from ..board.faults import FaultInjector
from ..board.power_models import PowerReading

if TYPE_CHECKING:
    from hil.timing.clock import Clock
from .lag import LagMonitor
from .models import BodyPhone, CompiledPlant, Plant, ServoModel
from .phone_faults import PhoneTamper

Array = NDArray[np.float64]
YIELD_S = 2e-4  # s: the pause a lagging world thread takes between chunks, so the board's server runs
_EPS = 1e-9  # s: slack on "a whole step fits before t"
LOOK_AHEAD_S = 0.05  # s: the most the plant steps ahead of the present in one batch (frames come sooner)
logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Truth:
    """The true attitude ``R`` (3, 3) body → ENU and body rate ``omega`` (3,) rad/s at ``t`` (board s), and
    the units' gimbal angles, gimbal rates and rotor speeds (n,)."""

    t: float
    R: Array
    omega: Array
    gimbal_angle: Array
    gimbal_rate: Array
    rotor_speed: Array


class DrivingBoard(Protocol):
    """What the world needs of the board whose pulses drive it: the Python emulator
    (:class:`firmware_sim.board.Board`) and the firmware under simavr
    (:class:`firmware_sim.avr.stepped.FirmwareBoard`) both have it. ``outputs``: the widths on the pins
    (µs, None: no pulse); ``drive_epoch`` moves whenever what the drives see changes (a frame, a reset, a
    channel dying), ``next_output_change_us`` says before when it cannot (µs of board time, barring those
    events); ``units`` turn widths into rates and speeds (their calibration maps) and draw power from the
    battery (``power``) by the states handed over in ``set_unit_states`` (or, as plain floats at every
    board event, ``hand_over``)."""

    config: BoardConfig
    faults: FaultInjector
    units: list[UnitModel]
    outputs: tuple[float | None, ...]
    drive_epoch: int
    power: PowerReading

    @property
    def gimbal_mode(self) -> GimbalMode: ...

    @property
    def clock(self) -> Clock: ...

    @property
    def now(self) -> float: ...

    def step(self, now: float | None = None) -> None: ...

    def next_deadline_us(self) -> float: ...

    def next_output_change_us(self) -> float: ...

    def set_unit_states(
        self,
        states: Sequence[UnitState] | None,
        at: float | None = None,
        rotor_accel: Sequence[float] | None = None,
    ) -> None: ...

    def hand_over(self, values: Sequence[float], at: float, rotor_accel: Sequence[float]) -> None: ...


class World:
    """``scenario`` (:class:`hil.scenario.Scenario`): spacecraft (``world_spacecraft``: the true one when a
    run disperses it), servos, phone, start attitude and gimbal angles; the rotors start at rest (the host
    spins them up). ``board``: the emulated board whose pulses drive it (its unit count must match the
    spacecraft's): the Python emulator, or the firmware under simavr
    (:class:`firmware_sim.avr.stepped.FirmwareBoard`, the same interface). ``compiled``: step
    :class:`.models.CompiledPlant` and the phone's compiled sampler (default) rather than the numpy
    references. ``state`` is the plant's :class:`PlantState` either way (built on demand); :meth:`truth`
    reads the flat state without building one."""

    advance_period_s = 0.05
    """How long one :meth:`advance_to` may span (s): the world hands the board its unit states at every
    board event within a call, so a lockstep runtime need not call it every plant step (it still brings
    the world to the present before each estimator and control activation)."""

    def __init__(
        self,
        scenario: object,
        board: DrivingBoard,
        seed: int | None = None,
        compiled: bool = True,
    ) -> None:
        from hil.scenario import Scenario

        assert isinstance(scenario, Scenario)
        if board.config.n_units != scenario.n_units:
            from protocol.errors import ConfigError

            raise ConfigError(
                f"the board has {board.config.n_units} units, the scenario's spacecraft {scenario.n_units}",
                "World",
            )
        self.scenario = scenario
        self.board = board
        self.tamper = PhoneTamper(board.faults)
        self.params = scenario.world_spacecraft
        self.plant = Plant(self.params)
        motor = board.config.motor
        # The drives respond as the board's own actuator model says; an ESC cannot brake, so a rotor whose
        # throttle drops (failsafe, disarm) coasts down.
        self.servo = ServoModel(
            self.params,
            replace(
                scenario.loop.servo,
                gimbal_time_constant_s=board.config.gimbal.time_constant_s,
                rotor_time_constant_s=motor.time_constant_s,
                coast_time_constant_s=motor.coast_time_constant_s,
            ),
        )
        self.step_s = scenario.loop.plant_step_s
        n = self.n = self.params.n_units
        self.t0 = board.now
        self.layout = CompiledPlant(self.plant)  # the flat state's layout (pack, unpack, views); numpy only
        self.compiled: CompiledPlant | None = self.layout if compiled else None
        size = self.layout.size
        index = np.arange(size, dtype=float)  # the layout's views of it are the units' columns
        c = self.layout
        units = (c.gimbal_angle_of(index), c.gimbal_rate_of(index), c.rotor_rate_of(index))
        self._unit_columns = np.concatenate(units).astype(np.int64)  # gimbal angles, rates, rotor speeds
        self._rows = np.zeros((64, size))  # row _at: the present; rows _at + 1 .. _head: stepped ahead
        self._at = self._head = 0
        self._work = np.zeros(size)
        self._sensed: list[SensorSample] = []  # what the phone sensed along the steps ahead (rows 0 .. head)
        self._sensed_in: list[int] = []  # each one's interval (its first row)
        self._row_t: list[float] = [0.0]  # each row's plant time (s), as Python floats for the loops below
        self._first_accel: list[float] = [0.0] * n  # row 0's rotor accelerations (the batch before's)
        self._row_units: list[list[float]] = [[0.0] * 3 * n]  # each row's unit columns, angles wrapped
        self._row_us: list[int] = [0]  # each row's board time in whole µs (events fall at these)
        self._given = 0  # how many of them the world has handed out (those before the present row)
        self._phone_at: tuple | None = None  # the phone as it was at row 0
        self.state = self.plant.state(
            R=scenario.slew.R0, gimbal_angle=scenario.slew.gimbal_angle0, rotor_rate=np.zeros(n), t=0.0
        )
        self.phone = BodyPhone(scenario.phone, scenario.seed if seed is None else seed, t0=self.t0)
        self._unclamped = np.zeros(1, bool)
        self._pushed_at: float | None = None
        self._read: tuple | None = None  # what the drives last read from the board (its drive epoch, mode)
        self._held: tuple | None = None
        self.steps = 0  # plant steps the world has moved through
        self.batches = 0  # compiled calls (each steps ahead to the next pulse frame)
        self.rewinds = 0  # times the steps ahead were dropped (an event changed what the drives see)
        board.set_unit_states(self.unit_states(), rotor_accel=self._first_accel)

    # ------------------------------------------------------------------ state
    @property
    def _flat(self) -> Array:
        """The present flat state (a view of the row the world has reached)."""
        return self._rows[self._at]

    @property
    def state(self) -> PlantState:
        """The plant's state now (batch 1, built from the flat state on each read)."""
        return self.layout.unpack(self._flat)

    @state.setter
    def state(self, s: PlantState) -> None:
        self._drop_ahead()
        self._rows[0] = self.layout.pack(s)
        self._row_t = [float(self._rows[0, 0])]
        self._first_accel = [0.0] * self.n
        self._row_units = self._listed_units(self._rows[:1, self._unit_columns])
        self._at = self._head = 0

    @property
    def now(self) -> float:
        """World time on the board's clock (s)."""
        return self.t0 + self._row_t[self._at]

    def truth(self) -> Truth:
        """The true motion now (copies; nothing else is built)."""
        c, f = self.layout, self._flat
        units = c.gimbal_angle_of(f).copy(), c.gimbal_rate_of(f).copy(), c.rotor_rate_of(f).copy()
        return Truth(self.now, c.R_of(f).copy(), c.omega_of(f).copy(), *units)

    def _listed_units(self, units: Array) -> list[list[float]]:
        """Rows of the unit columns (gimbal angles, gimbal rates, rotor speeds) as Python floats, for
        :meth:`_push` (which wraps the angles of the rows it hands over)."""
        return units.tolist()

    def unit_states(self, row: Array | None = None) -> list[UnitState]:
        """The units' states now (or in ``row``), as the board's telemetry reports them."""
        n = self.n
        v = (self._flat if row is None else row)[self._unit_columns].tolist()  # angles, rates, speeds
        return [UnitState(_wrap(v[i]), v[n + i], v[2 * n + i]) for i in range(n)]

    # ------------------------------------------------------------------ stepping
    def prepare(self) -> None:
        """Step the first batch ahead from the present (to the board's next pulse frame), so the world's
        first :meth:`advance_to` in real time finds it done: what a real-time world does before its
        board's server starts (its kernels loaded beforehand: :func:`load_kernels`)."""
        if self._at != self._head:
            return
        board, now = self.board, self.now
        self._reread()
        if round(now * 1e6) >= board.next_deadline_us():
            self._push(now, self._at)
            board.step(now)
            self._reread()
        self._look_ahead()

    def advance_to(self, t: float) -> list[SensorSample]:
        """Step the plant up to board time ``t`` (whole steps) and return the phone's samples meanwhile.

        The plant steps ahead in one batch to the board's next pulse frame (its pulses cannot change
        before, unless the MCU resets, a channel dies or the gimbal mode changes), possibly past ``t``.
        The world then moves through those steps to ``t``: each board event runs at the plant step it falls
        in, with the unit states of that step; should one change what the drives see, the steps ahead of
        it are dropped and the world steps again from there. What the phone sensed is handed out as the
        world moves, never ahead of it."""
        samples: list[SensorSample] = []
        h, board = self.step_s, self.board
        self._reread()  # the host's I/O may have stepped the board since the last call
        while self.now + h <= t + _EPS:
            if self._at == self._head:
                now = self.now
                if round(now * 1e6) >= board.next_deadline_us():  # events due now run before stepping on
                    self._push(now, self._at)
                    board.step(now)
                    self._reread()
                self._look_ahead()
            end, cut = self._through_events(self._last_row_by(t))
            samples += self._sample(end)
            self.steps += end - self._at
            self._at = end
            if cut:
                if end < self._head:
                    self._drop_ahead()
                    self.rewinds += 1
                self._reread()
        self._push(self.now, self._at)  # for whatever steps the board before the world's next call
        faults = board.faults
        if faults.phone_gaps:  # a phone that paused its stream (firmware-sim --phone-gap)
            samples = [s for s in samples if not faults.phone_silent(s.t_s)]
        if self.tamper.active:  # its clock jumps, hostile readings (--phone-jump, --phone-spoof)
            samples = self.tamper.apply(samples, self.now)
        return samples

    def _reread(self) -> None:
        """Drop the steps ahead and take the board's outputs anew if what the drives see has changed."""
        board = self.board
        if (board.drive_epoch, board.gimbal_mode) != self._read:
            if self._head > self._at:
                self._drop_ahead()
                self.rewinds += 1
            self._drive()

    def _push(self, at: float, k: int) -> None:
        """The unit states of row ``k`` (the world at board time ``at``) to the board (once per time), with
        the rotors' accelerations over the step that reached it: their power draw then follows the
        physics, not the spacing of the hand-overs (which depends on how the caller chunks time)."""
        if self._pushed_at != at:
            values = self._row_units[k]
            _wrap_angles(values, self.n)
            self.board.hand_over(values, at, self._rotor_accel(k))
            self._pushed_at = at

    def _rotor_accel(self, k: int) -> list[float]:
        """The rotors' accelerations (rad/s², n) over the plant step that reached row ``k``: their speed
        change over the step (row 0: carried over from the batch before). Worked out only for the rows
        handed to the board (about one in three), on the listed floats: the same subtraction and division
        a numpy pass over the batch makes."""
        if k == 0:
            return self._first_accel
        n, h = self.n, self.step_s
        now, before = self._row_units[k], self._row_units[k - 1]
        return [(now[i] - before[i]) / h for i in range(2 * n, 3 * n)]

    def _look_ahead(self) -> None:
        """Step from the present (at least one step) to the first step that starts at or after the board's
        next pulse frame (whole µs) — or at most :data:`LOOK_AHEAD_S` — keeping every state."""
        horizon_us = min(self.board.next_output_change_us(), round((self.now + LOOK_AHEAD_S) * 1e6))
        h, t0 = self.step_s, self.t0
        pt = float(self._flat[0])
        steps = 0
        while True:
            pt += h
            steps += 1
            if round((t0 + pt) * 1e6) >= horizon_us:
                break
        rows = self._rows
        if rows.shape[0] < steps + 1:  # a shorter plant step than any before: room for the new batch
            rows = np.zeros((2 * steps + 1, rows.shape[1]))
        rows[0] = self._rows[self._at]
        self._rows = rows
        self._first_accel = self._rotor_accel(self._at)
        self._at = 0
        self._head = steps
        self._run(steps)
        self.batches += 1
        self._phone_at = self.phone.checkpoint()
        times = rows[: steps + 1, 0]
        self._row_t = times.tolist()
        self._row_units = self._listed_units(rows[: steps + 1, self._unit_columns])
        self._row_us = np.rint((self.t0 + times) * 1e6).astype(np.int64).tolist()
        sensed, intervals = self._sense(0, steps)
        self._sensed, self._sensed_in = sensed, intervals.tolist()
        self._given = 0

    def _sense(self, start: int, end: int) -> tuple[list[SensorSample], NDArray[np.int64]]:
        """What the phone senses from row ``start`` to row ``end``, and the interval (its first row) each
        sample was taken in."""
        rows = self._rows[start : end + 1]
        if self.compiled is not None:
            path = rows[:, self.layout.path_columns]
            path[:, 0] += self.t0
            return self.phone.sample_path_intervals(path)
        out: list[SensorSample] = []
        intervals: list[int] = []
        c, t0 = self.layout, self.t0
        for i, (a, b) in enumerate(zip(rows[:-1], rows[1:], strict=True)):
            taken = self.phone.sample(
                t0 + a[0], c.R_of(a), c.omega_of(a), t0 + b[0], c.R_of(b), c.omega_of(b)
            )
            out += taken
            intervals += [start + i] * len(taken)
        return out, np.array(intervals, np.int64)

    def _sample(self, end: int) -> list[SensorSample]:
        """The phone's samples from the present row to row ``end`` (sensed when the world stepped ahead)."""
        upto = bisect.bisect_left(self._sensed_in, end)
        out = self._sensed[self._given : upto]
        self._given = upto
        return out

    def _drop_ahead(self) -> None:
        """Forget the steps ahead of the present, and what the phone sensed along them."""
        if self._head == self._at:
            return
        self._head = self._at
        assert self._phone_at is not None  # taken when the world stepped ahead
        self.phone.restore(self._phone_at)
        self._sense(0, self._at)  # the phone as it was at the present row (the samples are given already)
        self._phone_at = self.phone.checkpoint()
        self._sensed, self._sensed_in = self._sensed[: self._given], self._sensed_in[: self._given]

    def _run(self, steps: int) -> None:
        """``steps`` plant steps from row 0 under the held drives, each state into the next row."""
        rows, h = self._rows, self.step_s
        c = self.compiled
        if c is not None:
            work = self._work
            work[:] = rows[0]
            c.advance(work, h, steps, self.servo, rows[: steps + 1])
            return
        layout = self.layout
        for k in range(steps):
            rows[k + 1] = layout.pack(self.plant.step(layout.unpack(rows[k]), h, self.servo))

    def _last_row_by(self, t: float) -> int:
        """The last row stepped (past the present) whose time is ``t`` or before."""
        end, head = self._at + 1, self._head
        limit = t + _EPS - self.t0
        times = self._row_t
        while end < head and times[end + 1] <= limit:
            end += 1
        return end

    def _through_events(self, end: int) -> tuple[int, bool]:
        """Run the board's events due up to row ``end``, each at the first row at or after it with that
        row's unit states. Returns ``(end, cut)``: ``cut`` if an event changed what the drives see, ``end``
        then being its row."""
        board, row_us, t0 = self.board, self._row_us, self.t0
        k = self._at + 1
        while True:
            due_us = board.next_deadline_us()
            while k <= end and row_us[k] < due_us:
                k += 1
            if k > end:
                return end, False
            at = t0 + self._row_t[k]
            self._push(at, k)
            board.step(at)
            if (board.drive_epoch, board.gimbal_mode) != self._read:
                return k, True

    def _drive(self) -> None:
        """The drives' targets from the widths on the board's outputs now, at the battery voltage now (held
        anew only if they changed), worked out on Python floats: arrays are built only to hold new ones."""
        board = self.board
        self._read = (board.drive_epoch, board.gimbal_mode)
        outputs = board.outputs
        volts = board.power.battery_v
        mode = board.gimbal_mode
        gimbal: list[float] = []  # rad/s (0.0 while on an angle or without pulses)
        rotor: list[float] = []  # rad/s
        angle: list[float | None] = []  # rad, None: the gimbal follows its rate
        undriven: list[bool] = []
        for i, unit in enumerate(board.units):
            g_us, r_us = outputs[2 * i], outputs[2 * i + 1]
            if r_us is not None and not unit.rotor_dead:
                rotor.append(unit.rotor_speed_for(r_us, volts))
                undriven.append(False)
            else:  # no pulses or a dead ESC: no drive; the rotor coasts down
                rotor.append(0.0)
                undriven.append(True)
            if g_us is None or unit.gimbal_dead:
                gimbal.append(0.0)
                angle.append(None)
            elif mode is GimbalMode.RATE:
                gimbal.append(unit.gimbal_value_for(g_us, mode))
                angle.append(None)
            else:  # ANGLE: the servo's own position loop turns the gimbal to the target
                gimbal.append(0.0)
                angle.append(unit.gimbal_value_for(g_us, mode))
        held = (gimbal, rotor, angle, undriven)
        if held != self._held:
            self._held = held
            self.servo.hold(
                Setpoints(np.array([gimbal], dtype=float), np.array([rotor], dtype=float), self._unclamped),
                angle_target=np.array([[math.nan if a is None else a for a in angle]], dtype=float),
                rotor_undriven=np.array([undriven], dtype=bool),
            )


def load_kernels(scenario: object, config: object) -> None:
    """Load (from numba's disk cache, or compile) every kernel a world of ``scenario`` on a board of
    ``config`` (:class:`firmware_sim.board.config.BoardConfig`) runs, by flying a twin of it for a few
    pulse frames in lockstep: a real-time world whose kernels loaded on its first pass started hundreds of
    milliseconds behind its board's clock. Call it before the real board's clock starts."""
    from hil.timing.clock import LockstepClock

    from ..board import Board
    from ..board.config import BoardConfig

    assert isinstance(config, BoardConfig)
    clock = LockstepClock(0.0)
    twin = World(scenario, Board(config, clock))
    twin.prepare()
    end = 3.0 / config.frame_rate_hz + config.boot_time_s
    while clock.now() < end:
        clock.advance(twin.step_s * 10)
        twin.advance_to(clock.now())


def _wrap(angle: float) -> float:
    """An angle in (−π, π] (the telemetry's range)."""
    return math.remainder(angle, 2 * math.pi)


def _wrap_angles(values: list[float], n: int) -> None:
    """The first ``n`` of ``values`` (angles, rad) wrapped in place as :func:`_wrap` wraps them. An angle
    within ±π is its own remainder (π is half of 2π as floats; NaN is not within) and is left as it is,
    so wrapping twice changes nothing and costs four comparisons."""
    for i in range(n):
        angle = values[i]
        if not -math.pi <= angle <= math.pi:
            values[i] = _wrap(angle)


class WorldStreamer:
    """Runs a world in real time next to a board that is served elsewhere (a pty server's loop, a host's
    in-process emulator) and streams its phone the way a phone app does: a thread advances the world to
    the board's clock every ``step_s`` (under ``lock``, the lock the board's server holds while it touches
    the board) and sends the samples to ``phone_url`` (:func:`hil.link.sources.open_sender`: SensaGram's UDP
    datagrams, or Sensor Logger's HTTP Push batches). The sender's ``batch_s`` sets how often: each step
    for UDP, as an app batches for HTTP. A send nobody receives is counted, never fatal: a phone keeps
    streaming while the host restarts. An error in the thread is stored and raised by :meth:`check` /
    :meth:`close`."""

    def __init__(
        self, world: World, lock: threading.RLock | threading.Condition, phone_url: str, step_s: float = 0.005
    ) -> None:
        from hil.link.sources import open_sender

        self.world = world
        self.lock = lock
        self.sender = open_sender(phone_url)
        self.step_s = step_s
        self.batch_s = self.sender.batch_s
        self.batches = 0
        self.lag = LagMonitor()
        self._stop = threading.Event()
        self._thread_error = ThreadError("the world thread failed")
        self._thread = threading.Thread(target=self._run, name="world", daemon=True)

    @property
    def max_lag_s(self) -> float:
        """The furthest the world fell behind the board's clock after start-up (s)."""
        return self.lag.stats.max_lag_s

    def start(self) -> WorldStreamer:
        self._thread.start()
        return self

    def _run(self) -> None:
        clock, world = self.world.board.clock, self.world
        with self._thread_error.caught(logger, "world thread failed"):  # raised by check()/close()
            pending: list[SensorSample] = []
            origin = next_push = clock.now()
            k = 0
            wall = time.monotonic()
            while not self._stop.is_set():
                k += 1
                clock.sleep_until(origin + k * self.step_s)
                target = clock.now()
                work = 0.0
                # At most step_s of world per hold of the board's lock, then let its server in: a world
                # that runs behind (a loaded machine) must slow the phone, never starve the board's link.
                while world.now + world.step_s <= target + 1e-9 and not self._stop.is_set():
                    with self.lock:
                        began = time.monotonic()
                        pending += world.advance_to(min(target, world.now + self.step_s))
                        work += time.monotonic() - began
                    if world.now + world.step_s <= target + 1e-9:
                        time.sleep(YIELD_S)  # a real pause: a released lock is re-taken at once otherwise
                now_wall = time.monotonic()
                warning = self.lag.observe(clock.now() - world.now, now_wall - wall, work)
                wall = now_wall
                if warning is not None:
                    logger.warning("%s", warning)
                if pending and clock.now() >= next_push + self.batch_s:
                    next_push = clock.now()
                    self.sender.send(pending)
                    self.batches += 1
                    pending = []
                k = max(k, int((clock.now() - origin) / self.step_s))  # missed steps skipped, never burst

    def check(self) -> None:
        """Raise the world thread's error, if it had one (as every later call does)."""
        self._thread_error.check()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self.sender.close()
        self.check()
