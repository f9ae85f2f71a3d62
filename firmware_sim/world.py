"""The world on the far side of the board, for closed-loop emulation: the board's pulses drive the ESCs
and gimbal servos of a spacecraft with VSCMGs, and a phone on the spacecraft senses its motion.

The world reads the widths the board's timers put out (``Board.outputs``) and turns each into what the
motor driver makes of it through the unit's calibration map — the rotor ESC's steady speed at the present
battery voltage, the gimbal servo's rate (or angle) — and lets the drives of
:class:`hil.control.motor_loops.ServoModel` drive the plant (:mod:`hil.vscmg`) towards it. A channel
without pulses (board booting, outputs off, a dead ESC) leaves its drive where it was: the gimbal holds,
the rotor keeps its speed.

**Batches.** Those widths change only at the board's events (pulse frames, commands; the power manager's
samples change the battery voltage the ESC map reads), so the world steps the plant in compiled batches
from one board event to the next (``Board.next_deadline()``; the scenario's ``plant_step_s`` ≤ 1 ms per
step, several per call): :class:`hil.vscmg.CompiledPlant` with the drive law inside its integrator stages,
then :meth:`hil.simulation.phone.BodyPhone.sample_path` along the states it passed. At each event the unit
states go back to the board (``Board.set_unit_states``: its telemetry, power draw and dead-ESC detection
follow the physics at the board's own rates), the board runs what is due, and the drives take the new
widths — what a step-by-step loop would do, with the board's events at the same plant steps.
``World(..., compiled=False)`` runs the same schedule on the numpy :class:`hil.vscmg.Plant` and
:meth:`BodyPhone.sample`, one step at a time (the reference; the same samples and truth to rounding).

The world keeps the board's time: it is advanced to the board clock's present by :meth:`World.advance_to`
(the lockstep runtime calls it from its plant task; ``firmware-sim --world`` from its serving loop) and
returns the phone samples taken meanwhile. The truth (attitude, rate) is there for logs and metrics.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from hil.control.motor_loops import ServoModel, Setpoints
from hil.estimation.sensors import SensorSample
from hil.simulation.phone import BodyPhone
from hil.vscmg import CompiledPlant, Plant, PlantState
from protocol.messages import GimbalMode, UnitState

from .board import Board

Array = NDArray[np.float64]
YIELD_S = 2e-4  # s: the pause a lagging world thread takes between chunks, so the board's server runs
LAG_WARNING_S = 0.1  # s: a world this far behind the board's clock is reported (once)
_EPS = 1e-9  # s: slack on "a whole step fits before t"
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


class World:
    """``scenario`` (:class:`hil.scenario.Scenario`): spacecraft (``world_spacecraft``: the true one when a
    run disperses it), servos, phone, start attitude and gimbal angles; the rotors start at rest (the host
    spins them up). ``board``: the emulated board whose pulses drive it (its unit count must match the
    spacecraft's). ``compiled``: step :class:`hil.vscmg.CompiledPlant` and the phone's compiled sampler
    (default) rather than the numpy references. ``state`` is the plant's :class:`PlantState` either way
    (built on demand); :meth:`truth` reads the flat state without building one."""

    advance_period_s = 0.05
    """How long one :meth:`advance_to` may span (s): the world hands the board its unit states at every
    board event within a call, so a lockstep runtime need not call it every plant step (it still brings
    the world to the present before each estimator and control activation)."""

    def __init__(
        self, scenario: object, board: Board, seed: int | None = None, compiled: bool = True
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
        self.compiled: CompiledPlant | None = CompiledPlant(self.plant) if compiled else None
        self._flat = np.zeros(0)
        self._ref: PlantState | None = None
        self._path = np.zeros((64, 13))
        self.state = self.plant.state(
            R=scenario.slew.R0, gimbal_angle=scenario.slew.gimbal_angle0, rotor_rate=np.zeros(n), t=0.0
        )
        self.phone = BodyPhone(scenario.phone, scenario.seed if seed is None else seed, t0=self.t0)
        self._gimbal_sp = np.zeros((1, n))
        self._rotor_sp = np.zeros((1, n))
        self._angle = np.full((1, n), np.nan)
        self._undriven = np.zeros((1, n), bool)
        self._unclamped = np.zeros(1, bool)
        self._pushed_at: float | None = None
        self._read_at = -math.inf  # board time at which the drives last read the board's outputs
        self._held: tuple | None = None
        self.steps = 0
        self.batches = 0
        board.set_unit_states(self.unit_states())

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> PlantState:
        """The plant's state (batch 1; on the compiled plant built from the flat state on each read)."""
        if self.compiled is not None:
            return self.compiled.unpack(self._flat)
        assert self._ref is not None
        return self._ref

    @state.setter
    def state(self, s: PlantState) -> None:
        if self.compiled is not None:
            self._flat = self.compiled.pack(s)
        else:
            self._ref = s

    def _plant_t(self) -> float:
        return float(self._flat[0]) if self.compiled is not None else self._ref.t  # type: ignore[union-attr]

    @property
    def now(self) -> float:
        """World time on the board's clock (s)."""
        return self.t0 + self._plant_t()

    def _units(self) -> tuple[Array, Array, Array]:
        """Gimbal angles, gimbal rates and rotor speeds (n,), views of the state."""
        c = self.compiled
        if c is not None:
            f = self._flat
            return c.gimbal_angle_of(f), c.gimbal_rate_of(f), c.rotor_rate_of(f)
        s = self._ref
        assert s is not None
        return s.gimbal_angle[0], s.gimbal_rate[0], s.rotor_rate[0]

    def truth(self) -> Truth:
        """The true motion now (copies; nothing else is built)."""
        c = self.compiled
        if c is not None:
            R, omega = c.R_of(self._flat), c.omega_of(self._flat)
        else:
            assert self._ref is not None
            R, omega = self._ref.R[0], self._ref.omega[0]
        angle, rate, speed = self._units()
        return Truth(self.now, R.copy(), omega.copy(), angle.copy(), rate.copy(), speed.copy())

    def unit_states(self) -> list[UnitState]:
        angle, rate, speed = self._units()
        return [
            UnitState(_wrap(a), g, w)
            for a, g, w in zip(angle.tolist(), rate.tolist(), speed.tolist(), strict=True)
        ]

    # ------------------------------------------------------------------ stepping
    def advance_to(self, t: float) -> list[SensorSample]:
        """Step the plant up to board time ``t`` (whole steps) and return the phone's samples meanwhile: in
        batches from one board event to the next, the board's events run at the plant step they fall in."""
        samples: list[SensorSample] = []
        h, board = self.step_s, self.board
        while self.now + h <= t + _EPS:
            now = self.now
            due = board.next_deadline()
            if round(now * 1e6) >= due * 1e6 or board.now > self._read_at:
                # an event is due (pulse frame, power sample, command...), or the board moved on since the
                # drives last read it (a host's I/O steps it to the clock's now): hand it the unit states,
                # let it run what is due, and read its outputs
                self._push(now)
                board.step(now)
                self._drive()
                self._read_at = board.now
                due = board.next_deadline()
            samples += self._run(self._steps_before(due, t))
            self.batches += 1
        self._push(self.now)  # for whatever steps the board before the world's next call
        faults = board.faults
        if faults.phone_gaps:  # a phone that paused its stream (firmware-sim --phone-gap)
            samples = [s for s in samples if not faults.phone_silent(s.t_s)]
        return samples

    def _push(self, at: float) -> None:
        """The unit states at board time ``at`` to the board (once per time)."""
        if self._pushed_at != at:
            self.board.set_unit_states(self.unit_states(), at=at)
            self._pushed_at = at

    def _steps_before(self, deadline: float, t: float) -> int:
        """Plant steps from now (at least one) up to the first step that starts at or after the board's
        ``deadline`` (s, whole µs), without passing ``t``: the times the step-by-step loop would reach."""
        due_us = deadline * 1e6
        h, t0 = self.step_s, self.t0
        pt = self._plant_t()
        steps = 0
        while True:
            pt += h
            steps += 1
            now = t0 + pt
            if now + h > t + _EPS or round(now * 1e6) >= due_us:
                return steps

    def _run(self, steps: int) -> list[SensorSample]:
        """``steps`` plant steps under the held drives, and the phone's samples along them."""
        h = self.step_s
        self.steps += steps
        c = self.compiled
        if c is not None:
            if self._path.shape[0] < steps + 1:
                self._path = np.zeros((2 * steps + 1, 13))
            path = self._path[: steps + 1]
            c.advance(self._flat, h, steps, self.servo, path)
            path[:, 0] += self.t0
            return self.phone.sample_path(path)
        out: list[SensorSample] = []
        for _ in range(steps):
            prev = self._ref
            assert prev is not None
            s = self._ref = self.plant.step(prev, h, self.servo)
            out += self.phone.sample(
                self.t0 + prev.t, prev.R[0], prev.omega[0], self.t0 + s.t, s.R[0], s.omega[0]
            )
        return out

    def _drive(self) -> None:
        """The drives' targets from the widths on the board's outputs now (held anew only if they changed)."""
        board = self.board
        outputs = board.outputs
        volts = board.power.battery_v
        mode = board.gimbal_mode
        gimbal, rotor, angle, undriven = (
            self._gimbal_sp[0],
            self._rotor_sp[0],
            self._angle[0],
            self._undriven[0],
        )
        for i, unit in enumerate(board.units):
            g_us, r_us = outputs[2 * i], outputs[2 * i + 1]
            if r_us is not None and not unit.rotor_dead:
                rotor[i] = unit.rotor_speed_for(r_us, volts)
                undriven[i] = False
            else:  # no pulses or a dead ESC: no drive; the rotor keeps its speed (coasting is slow)
                rotor[i] = 0.0
                undriven[i] = True
            angle[i] = math.nan
            if g_us is None or unit.gimbal_dead:
                gimbal[i] = 0.0
            elif mode is GimbalMode.RATE:
                gimbal[i] = unit.gimbal_value_for(g_us, mode)
            else:  # ANGLE: the servo's own position loop turns the gimbal to the target
                gimbal[i] = 0.0
                angle[i] = unit.gimbal_value_for(g_us, mode)
        targets = [None if math.isnan(a) else a for a in angle.tolist()]
        held = (gimbal.tolist(), rotor.tolist(), targets, undriven.tolist())
        if held != self._held:
            self._held = held
            self.servo.hold(
                Setpoints(self._gimbal_sp.copy(), self._rotor_sp.copy(), self._unclamped),
                angle_target=self._angle.copy(),
                rotor_undriven=self._undriven.copy(),
            )


def _wrap(angle: float) -> float:
    """An angle in (−π, π] (the telemetry's range)."""
    return math.remainder(angle, 2 * math.pi)


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
        self.max_lag_s = 0.0  # the furthest the world fell behind the board's clock (s)
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="world", daemon=True)

    def start(self) -> WorldStreamer:
        self._thread.start()
        return self

    def _run(self) -> None:
        clock, world = self.world.board.clock, self.world
        try:
            pending: list[SensorSample] = []
            origin = next_push = clock.now()
            k = 0
            while not self._stop.is_set():
                k += 1
                clock.sleep_until(origin + k * self.step_s)
                target = clock.now()
                lag = target - world.now
                if lag > LAG_WARNING_S >= self.max_lag_s:
                    logger.warning(
                        "the world runs %.0f ms behind the board's clock: this machine cannot step the plant "
                        "in real time (the phone comes late and slow); lockstep runs are unaffected",
                        lag * 1e3,
                    )
                self.max_lag_s = max(self.max_lag_s, lag)
                # At most step_s of world per hold of the board's lock, then let its server in: a world
                # that runs behind (a loaded machine) must slow the phone, never starve the board's link.
                while world.now + world.step_s <= target + 1e-9 and not self._stop.is_set():
                    with self.lock:
                        pending += world.advance_to(min(target, world.now + self.step_s))
                    if world.now + world.step_s <= target + 1e-9:
                        time.sleep(YIELD_S)  # a real pause: a released lock is re-taken at once otherwise
                if pending and clock.now() >= next_push + self.batch_s:
                    next_push = clock.now()
                    self.sender.send(pending)
                    self.batches += 1
                    pending = []
                k = max(k, int((clock.now() - origin) / self.step_s))  # missed steps skipped, never burst
        except BaseException as exc:  # stored, raised by check(): threads never die silently
            self._error = exc
            logger.exception("world thread failed")

    def check(self) -> None:
        if self._error is not None:
            from protocol.errors import LinkError

            raise LinkError(f"the world thread failed: {self._error!r}") from self._error

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self.sender.close()
        self.check()
