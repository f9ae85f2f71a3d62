"""The host's control step, once per control period while the run steers (slew or hold): estimate and
reference → the geometric controller's torque demand → the steering law's gimbal rates and rotor
accelerations → the rotor-speed and gimbal-rate setpoints for the board. Also the two setpoints the host
sends when it does not steer: *hold* (gimbals still, rotors at nominal speed) and *rest* (nothing on board
turns: the first still window's, with the rotors at rest)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.control.attitude import AttitudeController, Reference
from hil.control.motor_loops import SetpointGenerator
from hil.control.steering import VscmgSteering
from hil.scenario import Scenario
from hil.so3.floats import Mat9, Vec3, vec3
from protocol.compiled import fast_constructor
from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint

Array = NDArray[np.float64]

_unit_setpoint = fast_constructor(UnitSetpoint)
_actuator_setpoint = fast_constructor(ActuatorSetpoint)
"""The wire message's records built by setting their slots (``UnitSetpoint(gimbal, rotor_speed)``,
``ActuatorSetpoint(gimbal_mode, units)``), not through a frozen dataclass's ``__init__`` (which sets each
field through ``object.__setattr__``): five records every control tick, 2.5 -> 1.8 µs together."""


@dataclass(slots=True)
class Steered:
    """One control step's result: ``setpoint`` the message for the board, ``torque`` (three floats) N m
    the controller asked of the array (L_r, body frame) and ``delta`` the array's singularity measure δ
    at the step's gimbal angles and rotor speeds. (Not ``frozen``, as
    :class:`hil.runtime.rows.TickSnapshot`: made on every control tick.)"""

    setpoint: ActuatorSetpoint
    torque: Vec3
    delta: float


class ControlStep:
    """Controller, steering and setpoint generator for ``scenario``'s spacecraft and loop settings. The
    controller's inertia is the plant's locked inertia at the scenario's initial gimbal angles."""

    def __init__(self, scenario: Scenario) -> None:
        from hil.vscmg import PlantModel

        params = scenario.spacecraft
        loop = scenario.loop
        plant = PlantModel(params)
        state0 = plant.state(gimbal_angle=scenario.slew.gimbal_angle0)
        self.controller = AttitudeController(plant.locked_inertia(state0)[0], loop.gains)
        self.steering = VscmgSteering(params, loop.steering)
        self.setpoints = SetpointGenerator(params, loop.control_rate_hz, loop.frame_rate_hz)
        self.dt = 1.0 / loop.control_rate_hz  # s, the control period
        n = params.n_units
        self.hold = ActuatorSetpoint(
            gimbal_mode=GimbalMode.RATE,
            units=tuple(UnitSetpoint(0.0, params.nominal_rotor_speed) for _ in range(n)),
        )
        self.rest = ActuatorSetpoint(
            gimbal_mode=GimbalMode.RATE,
            units=tuple(UnitSetpoint(0.0, 0.0) for _ in range(n)),
        )

    def reset(self, rotor: Array) -> None:
        """A new slew starts with the rotors at ``rotor`` (n,) rad/s: the setpoints from there, the
        controller's integral state from zero."""
        self.setpoints.reset(rotor)
        self.controller.reset()

    def step(
        self,
        attitude: Mat9,
        rate: Vec3,
        reference: Reference,
        gimbal: Sequence[float],
        rotor: Sequence[float],
    ) -> Steered:
        """One control period: the estimate ``attitude`` (body → inertial, a row-major 9-tuple) and
        ``rate`` (3 floats, rad/s) tracking ``reference``, with the array at ``gimbal`` (n,) rad and
        ``rotor`` (n,) rad/s (floats or arrays).

        On Python floats from end to end (the controller's :meth:`~AttitudeController.update_floats`,
        steering's one-row kernels, :meth:`~SetpointGenerator.update_floats`): the numbers of
        :meth:`step_arrays`, the composition of the batched calls it replaces (a test compares them),
        without the ~20 small arrays those make and read back every control tick."""
        steering, dt = self.steering, self.dt
        h = steering.momentum_one(gimbal, rotor)
        R_d, w_d, wd_d = reference.floats
        torque = self.controller.update_floats(attitude, rate, R_d, w_d, wd_d, dt, h)[0]
        rates, accels, delta = steering.solve_one(torque, gimbal, rotor, dt)
        measured = rotor.tolist() if isinstance(rotor, np.ndarray) else list(rotor)
        speeds, rates, _ = self.setpoints.update_floats(rates, accels, measured)
        units = tuple(map(_unit_setpoint, rates, speeds))  # (gimbal, rotor_speed): Python floats
        return Steered(_actuator_setpoint(GimbalMode.RATE, units), torque, delta)

    def step_arrays(
        self, attitude: Array, rate: Array, reference: Reference, gimbal: Array, rotor: Array
    ) -> Steered:
        """:meth:`step` through the batched, array-taking calls (B = 1): the path it replaced, kept as
        its oracle. ``attitude`` (3, 3), ``rate`` (3,) rad/s."""
        h = self.steering.momentum(gimbal, rotor)[0]
        out = self.controller.update(attitude, rate, reference, self.dt, h)
        cmd = self.steering.solve(out.torque, gimbal, rotor, self.dt)
        setpoints = self.setpoints.update(cmd, rotor)
        return Steered(setpoints.message(), vec3(out.torque), float(cmd.delta[0]))

    def delta(self, gimbal: ArrayLike, rotor: ArrayLike) -> float:
        """The array's singularity measure δ at ``gimbal`` (n,) rad and ``rotor`` (n,) rad/s."""
        return float(self.steering.delta(gimbal, rotor)[0])
