"""The host's control step, once per control period while the run steers (slew or hold): estimate and
reference → the geometric controller's torque demand → the steering law's gimbal rates and rotor
accelerations → the rotor-speed and gimbal-rate setpoints for the board. Also the two setpoints the host
sends when it does not steer: *hold* (gimbals still, rotors at nominal speed) and *rest* (nothing on board
turns: the first still window's, with the rotors at rest)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from hil.control.attitude import AttitudeController, Reference
from hil.control.motor_loops import SetpointGenerator
from hil.control.steering import VscmgSteering
from hil.scenario import Scenario
from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint

Array = NDArray[np.float64]


@dataclass(slots=True)
class Steered:
    """One control step's result: ``setpoint`` the message for the board, ``torque`` (3,) N m the
    controller asked of the array (L_r, body frame) and ``delta`` the array's singularity measure δ at the
    step's gimbal angles and rotor speeds. (Not ``frozen``, as :class:`hil.runtime.rows.TickSnapshot`:
    made on every control tick.)"""

    setpoint: ActuatorSetpoint
    torque: Array
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
        self, attitude: Array, rate: Array, reference: Reference, gimbal: Array, rotor: Array
    ) -> Steered:
        """One control period: the estimate ``attitude`` (3, 3) body → inertial and ``rate`` (3,) rad/s
        tracking ``reference``, with the array at ``gimbal`` (n,) rad and ``rotor`` (n,) rad/s."""
        h = self.steering.momentum(gimbal, rotor)[0]
        out = self.controller.update(attitude, rate, reference, self.dt, h)
        cmd = self.steering.solve(out.torque, gimbal, rotor, self.dt)
        setpoints = self.setpoints.update(cmd, rotor)
        return Steered(setpoints.message(), out.torque, float(cmd.delta[0]))

    def delta(self, gimbal: Array, rotor: Array) -> float:
        """The array's singularity measure δ at ``gimbal`` (n,) rad and ``rotor`` (n,) rad/s."""
        return float(self.steering.delta(gimbal, rotor)[0])
