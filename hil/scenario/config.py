"""What a scenario says about the loop and the manoeuvre, as the parts' own parameter types: the rates and
the controller's, steering's and drives' parameters (:class:`LoopConfig`), and the rest-to-rest slew
(:class:`SlewScenario`). The scenario reader (:mod:`hil.scenario.reader`) builds them from a TOML file; the
host (:mod:`hil.runtime.host`) and the emulator's world read them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.control.attitude import ControllerGains
from hil.control.motor_loops import ServoParams
from hil.control.steering import SteeringParams
from protocol.errors import ConfigError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class LoopConfig:
    """Rates and the pieces' parameters: ``plant_step_s`` the world's plant step (≤ 1 ms),
    ``control_rate_hz`` the host's control rate (≤ the board's pulse ``frame_rate_hz``, a whole number of
    plant steps), controller ``gains``, ``steering`` and drive (``servo``) parameters; ``warmup_s`` of
    holding still before the slew once the rotors are up (the estimator converges);
    ``calibrate_rate_bias``: average the raw gyroscope over the still window's second half and hand the
    bias to the estimator (the host's still-window calibration)."""

    plant_step_s: float = 1e-3
    control_rate_hz: float = 50.0
    frame_rate_hz: float = 50.0
    gains: ControllerGains = field(default_factory=lambda: ControllerGains(0.7, 0.9))
    steering: SteeringParams = field(default_factory=lambda: SteeringParams(null_gain=0.5))
    servo: ServoParams = field(default_factory=ServoParams)
    warmup_s: float = 2.0
    calibrate_rate_bias: bool = True

    def __post_init__(self) -> None:
        if not 0 < self.plant_step_s <= 1e-3:
            raise ConfigError(f"must be in (0, 1 ms], got {self.plant_step_s}", "LoopConfig.plant_step_s")
        if not (math.isfinite(self.control_rate_hz) and self.control_rate_hz > 0):
            raise ConfigError(f"must be positive, got {self.control_rate_hz}", "LoopConfig.control_rate_hz")
        if self.control_rate_hz > self.frame_rate_hz:
            raise ConfigError(
                f"the control rate ({self.control_rate_hz:g} Hz) must not exceed the pulse frame rate "
                f"({self.frame_rate_hz:g} Hz)",
                "LoopConfig.control_rate_hz",
            )
        steps = 1.0 / (self.control_rate_hz * self.plant_step_s)
        if abs(steps - round(steps)) > 1e-6:
            raise ConfigError("the control period must be a whole number of plant steps", "LoopConfig")
        if not (math.isfinite(self.warmup_s) and self.warmup_s >= 0):
            raise ConfigError(f"must be ≥ 0 s, got {self.warmup_s}", "LoopConfig.warmup_s")


@dataclass(frozen=True)
class SlewScenario:
    """A rest-to-rest slew: the spacecraft starts at ``R0`` (3, 3) body → inertial, the host slews to
    ``R_target`` (3, 3) within ``max_rate`` rad/s and ``max_accel`` rad/s², from gimbal angles
    ``gimbal_angle0`` (n,) rad; the run lasts ``duration_s`` from the slew's start."""

    name: str
    R0: Array
    R_target: Array
    duration_s: float = 40.0
    max_rate: float = 0.15
    max_accel: float = 0.025
    gimbal_angle0: ArrayLike = 0.0
