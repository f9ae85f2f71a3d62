"""The world on the far side of the board, for closed-loop emulation: the board's pulses drive the ESCs
and gimbal servos of a spacecraft with VSCMGs, and a phone on the spacecraft senses its motion.

Each plant step (the scenario's ``plant_step_s``, ≤ 1 ms) the world reads the widths the board's timers
put out (``Board.outputs``), turns each into what the motor driver makes of it through the unit's
calibration map — the rotor ESC's steady speed at the present battery voltage, the gimbal servo's rate
(or angle) — and lets :class:`hil.control.motor_loops.ServoModel` drive the plant (:mod:`hil.vscmg`)
towards it.
The measured unit states go back to the board (``Board.set_unit_states``: its telemetry, power draw
and
dead-ESC detection then follow the physics), and the phone (:class:`hil.simulation.phone.BodyPhone`)
samples the
true motion. A channel without pulses (board booting, outputs off) leaves its drive where it was: the
gimbal holds, the rotor holds its speed over such short gaps.

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
from hil.vscmg import Plant, PlantState
from hil.vscmg.fast import FastState, SingleRunPlant
from protocol.messages import GimbalMode, UnitState

from .board import Board

Array = NDArray[np.float64]
YIELD_S = 2e-4  # s: the pause a lagging world thread takes between chunks, so the board's server runs
LAG_WARNING_S = 0.1  # s: a world this far behind the board's clock is reported (once)
logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Truth:
    """The true attitude ``R`` (3, 3) body → ENU and body rate ``omega`` (3,) rad/s at ``t`` (board s)."""

    t: float
    R: Array
    omega: Array
    gimbal_angle: Array
    gimbal_rate: Array
    rotor_speed: Array


class World:
    """``scenario`` (:class:`hil.scenario.Scenario`): spacecraft, servos, phone, start attitude and
    gimbal angles; the rotors start at rest (the host spins them up). ``board``: the emulated board whose
    pulses drive it (its unit count must match the spacecraft's). ``fast``: step the plant with
    :class:`hil.vscmg.fast.SingleRunPlant` (plain floats, the same physics to rounding; default) rather
    than the numpy :class:`hil.vscmg.Plant` (the reference; ~5x the world's CPU at one run). ``state`` is the
    plant's :class:`PlantState` either way (built on demand on the fast path)."""

    def __init__(self, scenario: object, board: Board, seed: int | None = None, fast: bool = True) -> None:
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
        n = self.params.n_units
        self.t0 = board.now
        self.fast: SingleRunPlant | None = SingleRunPlant(self.plant) if fast else None
        self._state: PlantState | None = None
        self._fs: FastState | None = None
        self.state = self.plant.state(
            R=scenario.slew.R0, gimbal_angle=scenario.slew.gimbal_angle0, rotor_rate=np.zeros(n), t=0.0
        )
        self.phone = BodyPhone(scenario.phone, scenario.seed if seed is None else seed, t0=self.t0)
        self._gimbal_sp = np.zeros((1, n))
        self._rotor_sp = np.zeros((1, n))
        self.steps = 0
        board.set_unit_states(self.unit_states())

    @property
    def state(self) -> PlantState:
        """The plant's state (batch 1)."""
        if self._state is None:
            assert self.fast is not None and self._fs is not None
            self._state = self.fast.to_state(self._fs)
        return self._state

    @state.setter
    def state(self, s: PlantState) -> None:
        self._state = s
        if self.fast is not None:
            self._fs = self.fast.from_state(s)

    @property
    def now(self) -> float:
        """World time on the board's clock (s)."""
        return self.t0 + (self._fs.t if self._fs is not None else self.state.t)

    def truth(self) -> Truth:
        s = self.state
        return Truth(
            self.now, s.R[0].copy(), s.omega[0].copy(), s.gimbal_angle[0].copy(), s.gimbal_rate[0].copy(),
            s.rotor_rate[0].copy(),
        )  # fmt: skip

    def unit_states(self) -> list[UnitState]:
        if self._fs is not None:
            f = self._fs
            angle, rate, speed = f.gimbal_angle, f.gimbal_rate, f.rotor_rate
        else:
            s = self.state
            angle, rate, speed = s.gimbal_angle[0], s.gimbal_rate[0], s.rotor_rate[0]
        return [
            UnitState(float(_wrap(a)), float(g), float(w)) for a, g, w in zip(angle, rate, speed, strict=True)
        ]

    def advance_to(self, t: float) -> list[SensorSample]:
        """Step the plant up to board time ``t`` (whole steps) and return the phone's samples meanwhile."""
        if self.fast is not None:
            return self._advance_fast(t)
        samples: list[SensorSample] = []
        h = self.step_s
        while self.now + h <= t + 1e-9:
            self.board.step(self.now)  # the pulse frames due by now, at their own times
            self._drive()
            prev = self.state
            self.state = self.plant.step(prev, h, self.servo)
            self.steps += 1
            samples += self.phone.sample(
                self.t0 + prev.t, prev.R[0], prev.omega[0], self.now, self.state.R[0], self.state.omega[0]
            )
        self.board.set_unit_states(self.unit_states())
        return samples

    def _advance_fast(self, t: float) -> list[SensorSample]:
        """:meth:`advance_to` on the float plant: arrays only for the phone (the attitude and rate)."""
        assert self.fast is not None and self._fs is not None
        samples: list[SensorSample] = []
        h, t0, fast = self.step_s, self.t0, self.fast
        f = self._fs
        R_prev, omega_prev = f.R_matrix(), f.omega_array()
        while t0 + f.t + h <= t + 1e-9:
            self.board.step(t0 + f.t)  # the pulse frames due by now, at their own times
            self._drive()
            prev_t = f.t
            f = self._fs = fast.step(f, h, self.servo)
            self._state = None
            self.steps += 1
            R, omega = f.R_matrix(), f.omega_array()
            samples += self.phone.sample(t0 + prev_t, R_prev, omega_prev, t0 + f.t, R, omega)
            R_prev, omega_prev = R, omega
        self.board.set_unit_states(self.unit_states())
        return samples

    def _drive(self) -> None:
        """The drives' targets from the widths on the board's outputs now."""
        board = self.board
        outputs = board.outputs
        volts = board.power.battery_v
        mode = board.gimbal_mode
        if self._fs is not None:
            rotor_rate, gimbal_angle = self._fs.rotor_rate, self._fs.gimbal_angle
        else:
            rotor_rate, gimbal_angle = self.state.rotor_rate[0], self.state.gimbal_angle[0]
        for i, unit in enumerate(board.units):
            g_us, r_us = outputs[2 * i], outputs[2 * i + 1]
            if r_us is not None and not unit.rotor_dead:
                self._rotor_sp[0, i] = unit.rotor_speed_for(r_us, volts)
            else:  # no pulses or a dead ESC: no drive; the rotor keeps its speed (coasting is slow)
                self._rotor_sp[0, i] = rotor_rate[i]
            if g_us is None or unit.gimbal_dead:
                self._gimbal_sp[0, i] = 0.0
            elif mode is GimbalMode.RATE:
                self._gimbal_sp[0, i] = unit.gimbal_value_for(g_us, mode)
            else:  # ANGLE: the servo's own position loop, a proportional rate toward the target
                target = unit.gimbal_value_for(g_us, mode)
                err = math.remainder(target - float(gimbal_angle[i]), 2 * math.pi)
                limit = self.params.limits.max_gimbal_rate
                self._gimbal_sp[0, i] = max(-limit, min(limit, err / 0.1))
        self.servo.hold(Setpoints(self._gimbal_sp, self._rotor_sp, np.zeros(1, bool)))


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
