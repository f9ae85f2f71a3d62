"""The TOML reader behind :func:`hil.scenario.parse_scenario`: walks the document table by table, checks
every key and value, and builds the parts; every error names ``file: table.key``."""

from __future__ import annotations

import math
import unicodedata
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from hil import so3
from hil.control.attitude import ControllerGains
from hil.control.steering import SteeringParams
from hil.estimation.admission import ReadingLimits
from hil.estimation.params import directions_matrix
from hil.estimation.registry import DEFAULT_ESTIMATOR, EstimatorChoice
from hil.estimation.sensors import SensorKind
from hil.numbers import MAX_SEED, is_finite_number
from hil.scenario.fault_specs import check_fault_options
from hil.vscmg import SpacecraftParams
from protocol.errors import ConfigError, value_repr

from .config import LoopConfig, SlewScenario
from .model import Scenario
from .phone import PhoneSpec, SensorSpec

_SPACECRAFT_PRESETS = ("cubesat_1u", "air_bearing_testbed")
_GEOMETRIES = ("pyramid", "tetrahedron", "custom")
_GEOMETRY_KEYS: dict[str, frozenset[str]] = {
    "pyramid": frozenset({"geometry", "units", "skew_deg"}),
    "tetrahedron": frozenset({"geometry"}),  # three units, its own skew
    "custom": frozenset({"geometry", "gimbal_axes", "spin_axes"}),
}
"""The ``[array]`` keys each geometry takes: any other is refused, naming it (a tetrahedron's ``units = 6``
and a pyramid's ``gimbal_axes`` were dropped unsaid)."""
_CUSTOM_AXIS_KEYS = {"UnitParams.gimbal_axis": "array.gimbal_axes", "UnitParams.spin_axis": "array.spin_axes"}
"""The ``[array]`` key a custom array's unit check names (:func:`hil.vscmg.geometry.custom_array`: ``unit 2:
UnitParams.gimbal_axis``): the error was ``array.custom: unit 2: UnitParams.gimbal_axis: must have unit
length``, a key no file has; now ``array.gimbal_axes: unit 2: must have unit length``."""
_SENSOR_PRESETS = ("nexus5", "ideal")
_SENSOR_NAMES = {SensorKind.GYR: "gyroscope", SensorKind.ACC: "accelerometer", SensorKind.MAG: "magnetometer"}

# Every key each table accepts (anything else is a typo and an error naming it).
_KEYS: dict[str, frozenset[str]] = {
    "scenario": frozenset({"name", "description", "duration_s", "seed"}),
    "spacecraft": frozenset({"preset", "rotor_offset_m", "nominal_rotor_speed", "bus_inertia"}),
    "array": frozenset({"geometry", "units", "skew_deg", "gimbal_axes", "spin_axes"}),
    "sensors": frozenset({"preset", "gravity", "field_enu_uT", "gyr", "acc", "mag"}),
    "sensors.*": frozenset({"rate_hz", "noise", "bias", "jitter_s", "offset_s"}),
    "estimator": frozenset({"kind"}),  # and the kind's own keys (hil.estimation.registry checks them)
    "controller": frozenset(
        {
            "control_rate_hz",
            "plant_step_s",
            "natural_frequency",
            "damping",
            "null_gain",
            "wheel_weight",
            "mu",
            "warmup_s",
        }
    ),
    "board": frozenset(
        {"frame_rate", "telemetry_rate", "heartbeat_rate", "link_timeout", "mcu_watchdog", "cells", "soc"}
    ),
    "faults": frozenset(
        {
            "corrupt",
            "drop",
            "fault_direction",
            "stall",
            "hang_at",
            "sag",
            "sag_ohms",
            "brownout_at",
            "dead_esc",
        }
    ),
    "manoeuvre": frozenset(
        {
            "axis",
            "angle_deg",
            "max_rate",
            "max_accel",
            "initial_axis",
            "initial_angle_deg",
            "gimbal_angles_deg",
            "settle_deg",
        }
    ),
}


BOARD_RANGES: dict[str, tuple[float, float, type]] = {
    "frame_rate": (50.0, 490.0, float),
    "telemetry_rate": (0.1, 1000.0, float),
    "heartbeat_rate": (0.1, 1000.0, float),
    "link_timeout": (0.01, 60.0, float),
    "mcu_watchdog": (0.1, 8.0, float),  # firmware_sim.board.config.MCU_WATCHDOG_MIN_S
    "cells": (2, 12, int),
    "soc": (0.0, 1.0, float),
}
"""The board options a scenario may set (firmware-sim's spelling) and their ranges, checked here so an
error names the scenario's file and key; the board's own check (``firmware_sim.board.config.BoardConfig``)
agrees (tests/test_scenario_checks.py)."""
DEFAULT_LINK_TIMEOUT_S = 0.25
"""The board's link watchdog (s) when a scenario's ``[board]`` does not set ``link_timeout``
(``firmware_sim.board.config.BoardConfig``'s default; tests/test_scenario_checks.py holds them equal)."""
HOST_STALE_AFTER_S = 0.25
"""s: the host sees the board's telemetry, and the phone's gyroscope and accelerometer, as stale once their
newest is this old (``hil.runtime.faults.STALE_AFTER_S``, below this layer;
tests/test_config_beside_telemetry_rate.py holds them equal)."""
MIN_NEEDED_SENSOR_RATE_HZ = 2.0 / HOST_STALE_AFTER_S
"""The slowest ``sensors.gyr.rate_hz`` and ``sensors.acc.rate_hz`` a scenario (or a Monte Carlo draw) may
set: two readings per :data:`HOST_STALE_AFTER_S`, as for the board's telemetry. The host cannot steer
without both (``hil.runtime.phone_clock.NEEDED``): slower, each interval between readings is a phone gap
(a gyroscope at 3 Hz: 141 gaps in a 5 s run, which ended "lost: phone"). The magnetometer may be slower:
without it heading is only unobserved."""
NEEDED_SENSORS = ("gyr", "acc")
"""The sensors :data:`MIN_NEEDED_SENSOR_RATE_HZ` bounds."""
FIRMWARE_BATTERY_FULL_SCALE_V = 2.560 * 8
"""V: the most battery voltage the board's C firmware can read — its ADC's 2.56 V reference behind the
battery's 1/8 divider (``firmware/include/board_pins.h``: ``ADC_REF_MV``, ``BATTERY_DIVIDER_NUM``/``_DEN``;
tests/test_scenario_beside_firmware_cells.py holds them equal). The Python board emulator reads any
pack."""
CELL_FULL_V = 4.2
"""V: a full LiPo cell (firmware-sim's packs: ``firmware_sim.board.config``)."""
FIRMWARE_MAX_CELLS = int(FIRMWARE_BATTERY_FULL_SCALE_V // CELL_FULL_V)
"""The most ``[board] cells`` the firmware board takes: a full pack within its ADC's range (4: 16.8 V). Of
5 or more it read a full 6-cell pack as 20.46 V (the ADC's top), and a 12-cell pack's cells as 1.7 V each:
the board shed its load at once."""
MIN_RUN_SOC = 0.07
"""The least ``[board] soc`` (state of charge, 0..1) a run may start at: the pack's open-circuit cell voltage
there (3.54 V on firmware-sim's LiPo curve, ``firmware_sim.board.config.LIPO_OCV_CURVE``) is above the
board's WARN stage (``PowerThresholds.warn_v_cell``, 3.50 V; tests/test_hunt8_b_flat_pack.py holds them
so). Below it the board starts the run warning of a flat pack and, under the spin-up's load, limits the
rotors and sheds them: ``soc = 0`` shed at 0.16 s and the run ended "the slew never started", exit 1;
``soc = 0.05`` shed its rotors 54 s in. The board itself takes 0..1 (:data:`BOARD_RANGES`): a bench may
start one flat, a run cannot."""
DEFAULT_CELLS = 3
"""The board's cells when a scenario's ``[board]`` does not set them (firmware-sim's ``--cells`` default)."""
MIN_TELEMETRY_RATE_HZ = 2.0 / HOST_STALE_AFTER_S
"""The slowest ``[board] telemetry_rate`` a scenario may set: two frames per :data:`HOST_STALE_AFTER_S`, so
that one frame late or lost still leaves the host a live board. Slower (firmware-sim takes 0.1 Hz), every
frame is stale before the next comes and the host loses the board it is driving."""
DEFAULT_TELEMETRY_RATE_HZ = 20.0
"""The board's telemetry rate when a scenario's ``[board]`` does not set it (firmware-sim's default)."""
MAX_DURATION_S = 86_400.0
"""The longest run a scenario may ask for, warm-up included (a day of simulated time)."""
MAX_PLANT_STEPS = 100_000_000
"""The most plant steps a run may take (its warm-up and duration over ``plant_step_s``): a day at 1 ms is
86.4 million. A lockstep run takes a few hours for that many; more is a run that never ends."""
MAX_NAME_CHARS = 200
"""The longest ``[scenario] name`` (characters): one line on a terminal, a run directory's label (cut
further there, :func:`hil.files.output.safe_label`)."""
MIN_SKEW_DEG = 5.0
MIN_CUSTOM_UNITS = 3
"""The fewest units of a custom array, as of a pyramid (:func:`hil.vscmg.geometry.pyramid`): the CMG
Jacobian D1 is 3 × n, so with two units its rank is at most 2 and the singularity measure δ is 0 at every
gimbal angle. A custom array of two (on axes x and y) was taken: its run steered on the rotors' torque alone
and "completed" 20 deg off, δ 0 throughout."""
MAX_ANGLE_DEG = 360.0
"""deg: the most an attitude (``manoeuvre.initial_angle_deg``) or a gimbal angle may be turned, either way."""
MAX_SLEW_DEG = 180.0
"""deg: the most ``manoeuvre.angle_deg`` may turn, either way. The slew is rest-to-rest between two
attitudes and the host flies it the short way (:class:`hil.control.attitude.EigenaxisSlew` plans from the
rotation between them): a turn of 270 deg about an axis was flown, unsaid, as 90 deg about the opposite
one (its ``slew_start`` event said 91 deg), and 360 deg as no turn at all."""

READING_SIGMAS = 5.0
"""How many standard deviations of a sensor's spread (its bias, drawn once per axis, and its noise, per
sample: ``hypot(bias, noise)``) a scenario's phone must read within the range the host admits
(:class:`hil.estimation.admission.ReadingLimits`, a phone's: gyroscope 40 rad/s, accelerometer ~16 g,
magnetometer 5 mT), on top of what it reads at rest (nothing, gravity, the field's magnitude):
:func:`phone_out_of_range`. At 5 σ an axis strays out about once in 1.7 million readings. Beyond
that the host drops the readings as ``out_of_range``: a field of 10 mT (``field_enu_uT``'s bounds take
±1e4 µT an axis) had all 1 600 magnetometer readings of a run refused, the estimator steered without
heading and the run "completed"; a gyroscope bias of 50 rad/s had every gyroscope reading refused and the
run ended lost, a phone gap of 15 s — in a campaign, every run."""

RANGES: dict[str, tuple[float, float, str]] = {
    "spacecraft.rotor_offset_m": (-0.1, 0.1, "m"),
    "spacecraft.nominal_rotor_speed": (1.0, 2_000.0, "rad/s"),
    "spacecraft.bus_inertia": (-1e3, 1e3, "kg m²"),
    "array.gimbal_axes": (-1e3, 1e3, ""),
    "array.spin_axes": (-1e3, 1e3, ""),
    "sensors.gravity": (0.1, 100.0, "m/s²"),
    "sensors.field_enu_uT": (-1e4, 1e4, "µT"),
    "sensors.*.rate_hz": (1.0, 1_000.0, "Hz"),
    "sensors.*.noise": (0.0, 1e3, "(the sensor's unit)"),
    "sensors.*.bias": (0.0, 1e3, "(the sensor's unit)"),
    "sensors.*.jitter_s": (0.0, 0.1, "s"),
    "sensors.*.offset_s": (0.0, 10.0, "s"),
    "controller.control_rate_hz": (1.0, 490.0, "Hz"),
    "controller.plant_step_s": (1e-5, 1e-3, "s"),
    "controller.natural_frequency": (1e-3, 100.0, "rad/s"),
    "controller.damping": (1e-3, 10.0, ""),
    "controller.null_gain": (0.0, 100.0, "1/s"),
    "controller.wheel_weight": (0.0, 1e6, ""),
    "controller.mu": (0.0, 1e6, ""),
    "controller.warmup_s": (0.0, 600.0, "s"),
    "manoeuvre.angle_deg": (-MAX_SLEW_DEG, MAX_SLEW_DEG, "deg"),
    "manoeuvre.initial_angle_deg": (-MAX_ANGLE_DEG, MAX_ANGLE_DEG, "deg"),
    "manoeuvre.axis": (-1e6, 1e6, ""),
    "manoeuvre.initial_axis": (-1e6, 1e6, ""),
    "manoeuvre.max_rate": (1e-4, 10.0, "rad/s"),
    "manoeuvre.max_accel": (1e-5, 100.0, "rad/s²"),
    "manoeuvre.gimbal_angles_deg": (-MAX_ANGLE_DEG, MAX_ANGLE_DEG, "deg"),
    "manoeuvre.settle_deg": (1e-3, 180.0, "deg"),
}
"""Every number a scenario may set (``sensors.*`` for each of gyr, acc and mag; a vector's or matrix's
every element), and its bounds, inclusive — besides ``scenario.duration_s`` (positive, at most
:data:`MAX_DURATION_S` with the warm-up, at most :data:`MAX_PLANT_STEPS` plant steps:
:func:`check_run_length`), ``array.skew_deg`` (:data:`MIN_SKEW_DEG` from 0 and 90 deg) and
``array.units`` (2..8), checked with their reasons. Wide enough for any spacecraft and phone the
project models (a 1U CubeSat to an air-bearing table; phone sensors to 1 kHz), narrow enough that no value
makes a run that cannot end or cannot be simulated (a plant step of 1e-12 s, a warm-up of 1e9 s). Checked
as the file is read: an error names the file and the key. The board's options have their own,
:data:`BOARD_RANGES`."""

RANGE_REASONS: dict[str, str] = {
    "manoeuvre.angle_deg": (
        "the slew is flown the short way to its target attitude, so 270 deg about an axis would be 90 deg "
        "about the opposite one and 360 deg no turn at all; write the turn to fly (e.g. -90)"
    ),
}
"""Why a bound of :data:`RANGES` is where it is, said with the error where the number alone would not tell
what the file meant against what a run would do."""


def check_run_length(warmup_s: float, duration_s: float, plant_step_s: float, where: str) -> None:
    """Refuse a run whose simulated length (warm-up and duration) exceeds :data:`MAX_DURATION_S`, or
    that would take more than :data:`MAX_PLANT_STEPS` plant steps: a :class:`ConfigError` at ``where``
    (the file and key, or the option, that set the duration)."""
    length = warmup_s + duration_s
    if not (math.isfinite(length) and length <= MAX_DURATION_S):
        raise ConfigError(
            f"the run's simulated length, warm-up {warmup_s:g} s + duration {duration_s:g} s, must be at "
            f"most {MAX_DURATION_S:g} s",
            where,
        )
    steps = length / plant_step_s
    if steps > MAX_PLANT_STEPS:
        raise ConfigError(
            f"{length:g} s at a plant step of {plant_step_s:g} s is {steps:.3g} plant steps, more than "
            f"{MAX_PLANT_STEPS:.0e}: shorten the run or lengthen controller.plant_step_s",
            where,
        )


def needed_rate_error(kind: str, rate_hz: float) -> str:
    """Why a gyroscope's or accelerometer's ``rate_hz`` below :data:`MIN_NEEDED_SENSOR_RATE_HZ` is refused
    (the scenario's and a dispersion file's message)."""
    name = {"gyr": "gyroscope", "acc": "accelerometer"}[kind]
    return (
        f"a {name} at {rate_hz:g} Hz reads every {1.0 / rate_hz:g} s, but the host sees the phone stale once "
        f"its {name} is {HOST_STALE_AFTER_S:g} s old and needs two readings within that to steer: at least "
        f"{MIN_NEEDED_SENSOR_RATE_HZ:g} Hz (the magnetometer may be slower)"
    )


def check_firmware_board(scenario: Scenario) -> None:
    """Refuse ``[board] cells`` the firmware board cannot read when it is the board ``scenario`` runs
    (``board_options["board"] == "firmware"``, :meth:`~hil.scenario.model.Scenario.with_board`): more
    than :data:`FIRMWARE_MAX_CELLS`, whose full voltage is beyond its ADC's
    :data:`FIRMWARE_BATTERY_FULL_SCALE_V`. A :class:`ConfigError` at ``FILE: board.cells`` naming the
    firmware's limit. The Python board keeps the scenario's range."""
    board_options = scenario.board_options
    where = scenario.path.name if scenario.path is not None else "<scenario>"
    if board_options.get("board") != "firmware":
        return
    cells = board_options.get("cells", DEFAULT_CELLS)
    if cells > FIRMWARE_MAX_CELLS:
        raise ConfigError(
            f"{cells} cells are {cells * CELL_FULL_V:g} V full, beyond the {FIRMWARE_BATTERY_FULL_SCALE_V:g} "
            "V the firmware board's ADC reads (firmware/include/board_pins.h): it would read the pack wrong "
            f"and shed its load; at most {FIRMWARE_MAX_CELLS} cells with the firmware board (the Python "
            f"emulator takes {BOARD_RANGES['cells'][0]:g}..{BOARD_RANGES['cells'][1]:g})",
            f"{where}: board.cells",
        )


def phone_out_of_range(phone: PhoneSpec) -> tuple[str, str] | None:
    """Where a phone reads beyond what the host admits (:data:`READING_SIGMAS`), or None: at rest, each
    sensor's axis reads its true value (gyroscope 0 rad/s; accelerometer up to ``gravity`` m/s²,
    magnetometer up to the field's magnitude µT, on whichever axis the attitude turns them to) plus its
    bias and noise. The key under ``sensors`` that puts it out — ``field_enu_uT`` (or ``gravity``) when
    the true value alone does, else ``<kind>.noise`` or ``<kind>.bias``, the larger — and why. One check for
    a scenario's file and whatever else builds a phone from one (a Monte Carlo draw)."""
    limits = ReadingLimits()
    at_rest = {
        SensorKind.GYR: (0.0, ""),
        SensorKind.ACC: (phone.gravity, "gravity"),
        SensorKind.MAG: (float(np.linalg.norm(phone.field_enu_uT)), "field_enu_uT"),
    }
    for kind, (true_value, true_key) in at_rest.items():
        spec = phone.spec(kind)
        limit = limits.limit(kind)
        reach = true_value + READING_SIGMAS * math.hypot(spec.bias, spec.noise)
        if reach <= limit:
            continue
        unit, name = kind.unit, _SENSOR_NAMES[kind]
        if true_value > limit:
            key, reads = true_key, f"{true_value:g} {unit} at rest"
        else:
            key = f"{kind.label}.{'noise' if spec.noise >= spec.bias else 'bias'}"
            reads = (
                f"{true_value:g} {unit} at rest and {READING_SIGMAS:g} σ of its bias {spec.bias:g} and noise "
                f"{spec.noise:g} {unit}, {reach:g} {unit}"
            )
        return key, (
            f"the {name} would read {reads}, beyond the {limit:g} {unit} a phone's {name} measures "
            "(hil.estimation.admission.ReadingLimits): the host would drop its readings as out of range"
        )
    return None


def spin_up_rate(spacecraft: SpacecraftParams, gimbal_angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The array's momentum (3,) N m s, body frame, with every rotor at the nominal speed and the gimbals
    still at ``gimbal_angles`` (n,) rad, and the body rate (3,) rad/s it gives a spacecraft that was at
    rest with its rotors stopped: the system's momentum stays zero through the spin-up, so the bus takes
    the opposite, ``ω = −J⁻¹ h`` (``J`` the locked inertia about the centre of mass)."""
    from hil.vscmg.plant_model import PlantModel

    plant = PlantModel(spacecraft)
    state = plant.state(gimbal_angle=gimbal_angles)
    momentum = plant.array_momentum(state)[0]
    return momentum, -np.linalg.solve(plant.locked_inertia(state)[0], momentum)


ZERO_MOMENTUM_TOLERANCE = 1e-9
"""The net rotor momentum, as a fraction of the array's total (n h̄), below which the rotors' momenta
cancel (rounding; a pyramid's at zero gimbal angles is ~1e-16)."""


def _rotor_momenta(spacecraft: SpacecraftParams) -> np.ndarray:
    """Each rotor's spin momentum at the nominal speed (n,) N m s."""
    return np.array([u.rotor_spin_inertia for u in spacecraft.units]) * spacecraft.nominal_rotor_speed


def spin_up_momentum_cancels(spacecraft: SpacecraftParams, gimbal_angles: np.ndarray) -> bool:
    """Whether the rotors' spin momenta at the nominal speed cancel (within
    :data:`ZERO_MOMENTUM_TOLERANCE`) at ``gimbal_angles`` (n,) rad."""
    from hil.vscmg.geometry import spin_axes_at

    h = _rotor_momenta(spacecraft)
    net = h @ spin_axes_at(spacecraft.units, gimbal_angles)
    return bool(np.linalg.norm(net) <= ZERO_MOMENTUM_TOLERANCE * h.sum())


ZERO_MOMENTUM_STARTS = 64
"""How many starts :func:`zero_momentum_gimbal_angles` tries (zero, then drawn angles, the same on every
machine): from zero alone Gauss-Newton stalls where the net momentum's gradient vanishes (two units on one
gimbal axis, another across it, cancel at ±60 deg but not on the way from zero)."""


def zero_momentum_gimbal_angles(spacecraft: SpacecraftParams, iterations: int = 60) -> np.ndarray | None:
    """Gimbal angles (n,) rad, each in (−π, π], at which the rotors' spin momenta at the nominal speed
    cancel (within :data:`ZERO_MOMENTUM_TOLERANCE`), or None when none of :data:`ZERO_MOMENTUM_STARTS`
    Gauss-Newton searches (steps of least norm) finds any. Of those found, the nearest zero (three units
    on x, y and z, spinning along y, z and x at zero, cancel at −45 deg each)."""
    units = spacecraft.units
    h = _rotor_momenta(spacecraft)
    g = np.array([u.gimbal_axis for u in units], dtype=float)
    s0 = np.array([u.spin_axis for u in units], dtype=float)
    t0 = np.cross(g, s0)
    starts = np.random.default_rng(0).uniform(-np.pi, np.pi, (ZERO_MOMENTUM_STARTS, len(units)))
    starts[0] = 0.0
    found: list[np.ndarray] = []
    for gamma in starts:
        for _ in range(iterations):
            net = h @ (np.cos(gamma)[:, None] * s0 + np.sin(gamma)[:, None] * t0)
            if np.linalg.norm(net) <= ZERO_MOMENTUM_TOLERANCE * h.sum():
                found.append(np.angle(np.exp(1j * gamma)))  # wrapped into (−π, π]
                break
            across = (np.cos(gamma)[:, None] * t0 - np.sin(gamma)[:, None] * s0) * h[:, None]  # ∂net/∂γᵢ
            gamma = gamma - np.linalg.lstsq(across.T, net, rcond=None)[0]
        if found and not found[-1].any():
            break  # zero itself: none nearer
    return min(found, key=lambda angles: float(np.linalg.norm(angles))) if found else None


GIMBAL_COUPLING_MARGIN = 2.0 / 3.0
"""The most the gimbal-bus coupling λ (:func:`gimbal_bus_coupling`, 1/s) may be of the gimbal servo's rate
1/τ_g: λ τ_g ≤ 2/3. Each gimbal's rate servo (``hil.control.motor_loops.ServoParams``, the world's drive law
``u = I_g (γ̇_sp − γ̇)/τ_g`` with the gyroscopic load rejected) turns its gimbal against the bus, and the bus
turns back under it: a gimbal rate γ̇ⱼ moves the array's momentum by h̄ tⱼ γ̇ⱼ, the bus takes the opposite,
``ω̇ = −h̄ J⁻¹ T γ̇``, and each gimbal, whose conjugate momentum is ``I_g (γ̇ᵢ + gᵢ·ω)``, is carried along by
``gᵢ·ω̇``. Linearised, ``γ̈ = −γ̇/τ_g + h̄ Gᵀ J⁻¹ T γ̇``: the gimbals' mode along the coupling's largest
eigenvalue λ decays at ``1/τ_g − λ`` — unstable beyond λ τ_g = 1, and at λ τ_g = 2/3 already three times as
slow as the servo alone (its time constant τ_g/(1 − λ τ_g)), too slow for the host's steering, which
expects the gimbals to follow within τ_g. Measured on the 1U CubeSat (``hil run``, 90 deg slew): λ τ_g of
0.18 (the shipped 2e-3 kg m²), 0.56 and 0.62 settled in 22 s; 0.74 only at the run's end; 0.75 ended 10 deg
off; 0.83-0.93 (a bus of 3e-4 kg m²: h̄/J 13 rad/s) tumbled, the gimbals racing away from their commanded
rates, and "completed" 179 deg off."""


def gimbal_bus_coupling(spacecraft: SpacecraftParams, gimbal_angles: np.ndarray) -> float:
    """λ (1/s): the largest real part of the eigenvalues of ``h̄ Gᵀ J⁻¹ T`` at ``gimbal_angles`` (n,) rad —
    ``G`` the gimbal axes (n, 3), ``T`` the transverse axes ``gᵢ × sᵢ`` (n, 3), ``J`` the locked inertia about
    the centre of mass (kg m²), h̄ the nominal wheel momentum (N m s): how fast a gimbal's motion, through
    the bus it turns, drives the gimbals' own rates (:data:`GIMBAL_COUPLING_MARGIN`). It grows as h̄/J: a
    small bus, fast rotors."""
    from hil.vscmg.plant_model import PlantModel

    plant = PlantModel(spacecraft)
    inertia = plant.locked_inertia(plant.state(gimbal_angle=gimbal_angles))[0]
    return _coupling(spacecraft, gimbal_angles, inertia)


def _coupling(spacecraft: SpacecraftParams, gimbal_angles: np.ndarray, inertia: np.ndarray) -> float:
    """:func:`gimbal_bus_coupling` at a given locked inertia (3, 3) kg m²."""
    from hil.vscmg.geometry import spin_axes_at

    gimbal_axes = np.array([u.gimbal_axis for u in spacecraft.units], dtype=float)
    transverse = np.cross(gimbal_axes, spin_axes_at(spacecraft.units, gimbal_angles))
    coupling = spacecraft.nominal_wheel_momentum * gimbal_axes @ np.linalg.solve(inertia, transverse.T)
    return float(np.max(np.linalg.eigvals(coupling).real))


def least_bus_scale(spacecraft: SpacecraftParams, gimbal_angles: np.ndarray, gimbal_tau_s: float) -> float:
    """The factor the bus inertia must be scaled by (> 1) for the coupling to meet
    :data:`GIMBAL_COUPLING_MARGIN` with a gimbal servo of time constant ``gimbal_tau_s`` (s), the units'
    own inertia kept: bisected on the scale (λ falls as the bus grows); 1.0 when it already does."""
    from hil.vscmg.params import inertia_tensor
    from hil.vscmg.plant_model import PlantModel

    plant = PlantModel(spacecraft)
    locked = plant.locked_inertia(plant.state(gimbal_angle=gimbal_angles))[0]
    bus = inertia_tensor(spacecraft.bus_inertia, "bus_inertia")
    limit = GIMBAL_COUPLING_MARGIN / gimbal_tau_s

    def fits(scale: float) -> bool:
        return _coupling(spacecraft, gimbal_angles, locked + (scale - 1.0) * bus) <= limit

    if fits(1.0):
        return 1.0
    low, high = 1.0, 2.0
    while not fits(high):  # λ falls as 1/scale once the bus dominates: a few doublings
        low, high = high, high * 2.0
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (low, middle) if fits(middle) else (middle, high)
    return high


class _Reader:
    """Walks the TOML document table by table; every error names ``file: table.key``."""

    def __init__(self, doc: dict[str, Any], where: str) -> None:
        self.doc = doc
        self.where = where
        unknown = set(doc) - {k for k in _KEYS if "." not in k}
        if unknown:
            shown = value_repr(sorted(unknown))
            raise ConfigError(
                f"unknown table(s) {shown}; known: {sorted(k for k in _KEYS if '.' not in k)}", where
            )

    def table(self, name: str, keys: str | None = None) -> dict[str, Any]:
        parts = name.split(".")
        node: Any = self.doc
        for part in parts:
            node = node.get(part, {}) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            raise self.error(name, "must be a table")
        allowed = _KEYS[keys or name]
        for key in node:
            if key not in allowed:
                raise self.error(
                    f"{name}.{_key_shown(key)}", f"unknown key; known: {', '.join(sorted(allowed))}"
                )
        return node

    def error(self, key: str, detail: str) -> ConfigError:
        return ConfigError(detail, f"{self.where}: {key}")

    def number(
        self, tbl: dict[str, Any], table: str, key: str, default: float, positive: bool = True
    ) -> float:
        """A number at ``table.key`` (``default`` when absent): finite, positive unless told otherwise, and
        within its :data:`RANGES`."""
        value = tbl.get(key, default)
        if not is_finite_number(value):
            raise self.error(f"{table}.{key}", f"must be a number, got {value_repr(value)}")
        if positive and value <= 0:
            raise self.error(f"{table}.{key}", f"must be positive, got {value_repr(value)}")
        self.in_range(table, key, value)
        return float(value)

    def in_range(self, table: str, key: str, value: float) -> None:
        """Refuse ``value`` outside the :data:`RANGES` of ``table.key`` (``sensors.<kind>`` as
        ``sensors.*``)."""
        pattern = "sensors.*" if table.startswith("sensors.") else table
        bounds = RANGES.get(f"{pattern}.{key}")
        if bounds is not None and not bounds[0] <= value <= bounds[1]:
            lo, hi, unit = bounds
            why = RANGE_REASONS.get(f"{pattern}.{key}")
            raise self.error(
                f"{table}.{key}",
                f"must be within {lo:g}..{hi:g}{' ' + unit if unit else ''}, got {value_repr(value)}"
                + (f": {why}" if why else ""),
            )

    def vector(self, tbl: dict[str, Any], table: str, key: str, shape: tuple[int, ...]) -> np.ndarray:
        arr = _numbers(tbl[key])
        if arr is None:
            raise self.error(f"{table}.{key}", f"must be numbers, got {value_repr(tbl[key])}")
        if arr.shape != shape or not np.all(np.isfinite(arr)):
            raise self.error(
                f"{table}.{key}", f"must be finite numbers of shape {shape}, got {value_repr(tbl[key])}"
            )
        for element in arr.ravel():
            self.in_range(table, key, float(element))
        return arr

    def choice(self, tbl: dict[str, Any], table: str, key: str, options: tuple[str, ...]) -> str:
        value = tbl.get(key, options[0])
        if value not in options:
            raise self.error(
                f"{table}.{key}", f"must be one of {', '.join(options)}; got {value_repr(value)}"
            )
        return str(value)

    def text(
        self, tbl: dict[str, Any], table: str, key: str, limit: int = 2000, one_line: bool = False
    ) -> str:
        """A string at ``table.key`` ("" when absent), at most ``limit`` characters, of printable
        characters and spaces only (line breaks and tabs too unless ``one_line``); no control or format
        character (an escape, a bidirectional override, a line separator). The scenario's name and
        description are printed to the terminal as a run starts (``hil run``, ``hil report``) and written
        into every run's summary and every campaign's manifest: a TOML escape such as
        ``"\\u001b]0;…\\u0007"`` was the terminal's command, a name of 15 million characters went whole
        into each of them."""
        value = tbl.get(key, "")
        if not isinstance(value, str) or len(value) > limit:
            raise self.error(f"{table}.{key}", f"must be a string of at most {limit} characters")
        allowed = "" if one_line else "\n\t"
        unprintable = sorted(
            {c for c in value if not (c.isprintable() or c in allowed or unicodedata.category(c) == "Zs")}
        )
        if unprintable:
            codes = ", ".join(f"U+{ord(c):04X}" for c in unprintable[:5])
            lines = "" if one_line else " (a line break or tab aside)"
            raise self.error(
                f"{table}.{key}",
                f"must be printable text{lines}; has the control or format character(s) {codes}",
            )
        return value

    # ------------------------------------------------------------------ the tables
    def scenario(self, text: str, path: Path | None) -> Scenario:
        head = self.table("scenario")
        if not isinstance(head.get("name"), str) or not head["name"].strip():
            raise self.error("scenario.name", "required: a non-empty string")
        name = self.text(head, "scenario", "name", limit=MAX_NAME_CHARS, one_line=True)
        seed = head.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed <= MAX_SEED:
            raise self.error("scenario.seed", f"must be an integer in 0..{MAX_SEED}, got {_seed_shown(seed)}")
        spacecraft = self.spacecraft()
        loop = self.controller()
        duration = self.number(head, "scenario", "duration_s", 40.0)
        if duration > MAX_DURATION_S:
            raise self.error(
                "scenario.duration_s", f"must be at most {MAX_DURATION_S:g} s, got {value_repr(duration)}"
            )
        check_run_length(loop.warmup_s, duration, loop.plant_step_s, f"{self.where}: scenario.duration_s")
        slew, settle = self.manoeuvre(spacecraft, duration)
        self.check_gimbal_coupling(spacecraft, slew, loop)
        board = self.options("board")
        for key, value in board.items():
            lo, hi, kind = BOARD_RANGES[key]
            ok = not isinstance(value, bool) and (
                isinstance(value, int) if kind is int else isinstance(value, int | float)
            )
            if not ok or not (math.isfinite(value) and lo <= value <= hi):
                what = "an integer" if kind is int else "a number"
                raise self.error(f"board.{key}", f"must be {what} in {lo:g}..{hi:g}, got {value_repr(value)}")
        soc = board.get("soc")
        if soc is not None and soc < MIN_RUN_SOC:
            raise self.error(
                "board.soc",
                f"a pack at {soc:g} of its charge is below {MIN_RUN_SOC:g}, where its open-circuit voltage "
                "falls below the board's warning stage: the board would limit and then shed the rotors under "
                "the spin-up's load (power SHED), and the run could not fly its slew; "
                f"at least {MIN_RUN_SOC:g}",
            )
        faults = self.options("faults")
        check_fault_options(faults, 2 * spacecraft.n_units, f"{self.where}: faults")
        frame_rate = float(board.get("frame_rate", 50.0))  # firmware-sim's default
        if frame_rate < loop.control_rate_hz:
            raise self.error(
                "board.frame_rate", "must be at least controller.control_rate_hz (firmware-sim's default: 50)"
            )
        link_timeout = float(board.get("link_timeout", DEFAULT_LINK_TIMEOUT_S))
        period = 1.0 / loop.control_rate_hz
        if period >= link_timeout:
            # the host's setpoints are what feed the board's link watchdog: one per control period
            raise self.error(
                "controller.control_rate_hz",
                f"{loop.control_rate_hz:g} Hz sends the board a command every {period:g} s, not within its "
                f"link timeout of {link_timeout:g} s (board.link_timeout): the board would fail safe between "
                "commands; raise the rate or the timeout",
            )
        telemetry_rate = float(board.get("telemetry_rate", DEFAULT_TELEMETRY_RATE_HZ))
        if telemetry_rate < MIN_TELEMETRY_RATE_HZ:
            raise self.error(
                "board.telemetry_rate",
                f"{telemetry_rate:g} Hz is a frame every {1.0 / telemetry_rate:g} s, but the host sees the "
                f"board stale once its telemetry is {HOST_STALE_AFTER_S:g} s old and needs two frames within "
                f"that to keep it live: at least {MIN_TELEMETRY_RATE_HZ:g} Hz",
            )
        return Scenario(
            name=name,
            description=self.text(head, "scenario", "description"),
            spacecraft=spacecraft,
            phone=self.sensors(),
            estimator=self.estimator(),
            loop=replace(loop, frame_rate_hz=frame_rate),
            slew=slew,
            settle_deg=settle,
            seed=seed,
            board_options=board,
            fault_options=faults,
            source=text,
            path=path,
        )

    def check_gimbal_coupling(
        self, spacecraft: SpacecraftParams, slew: SlewScenario, loop: LoopConfig
    ) -> None:
        """Refuse a spacecraft whose gimbals the bus would carry away from their servos
        (:data:`GIMBAL_COUPLING_MARGIN`): a bus too small for its rotors' momentum. The error names
        ``spacecraft.bus_inertia`` (else ``nominal_rotor_speed``, else the array, whichever the file set)
        and the least bus inertia that would do at this momentum."""
        from hil.vscmg.params import inertia_tensor

        gimbals = np.asarray(slew.gimbal_angle0, dtype=float) * np.ones(spacecraft.n_units)
        tau = loop.servo.gimbal_time_constant_s
        coupling = gimbal_bus_coupling(spacecraft, gimbals)
        if coupling * tau <= GIMBAL_COUPLING_MARGIN:
            return
        sc = self.doc.get("spacecraft", {})
        key = next((f"spacecraft.{k}" for k in ("bus_inertia", "nominal_rotor_speed") if k in sc), "array")
        scale = least_bus_scale(spacecraft, gimbals, tau)
        least = scale * np.diag(inertia_tensor(spacecraft.bus_inertia, "bus_inertia"))
        diagonal = ", ".join(f"{_round_up(m):g}" for m in least)
        raise self.error(
            key,
            f"the bus is too small for its rotors' momentum: a gimbal's motion turns the bus, which carries "
            f"the gimbals with it at λ = {coupling:.3g} 1/s (h̄ = {spacecraft.nominal_wheel_momentum:.3g} "
            f"N m s over the locked inertia), against their servos' 1/τ_g = {1.0 / tau:g} 1/s: λ τ_g = "
            f"{coupling * tau:.2f}, beyond {GIMBAL_COUPLING_MARGIN:.2f} the gimbals no longer follow their "
            "commands (unstable beyond 1) and the run tumbles; give a bus inertia at least "
            f"{_round_up(scale):g} times this one (a diagonal of [{diagonal}] kg m²), or slower rotors "
            "(spacecraft.nominal_rotor_speed)",
        )

    def estimator(self) -> EstimatorChoice:
        """``[estimator]``: ``kind`` (default ``variational``) and that kind's own settings, which the kind
        checks (:class:`~hil.estimation.registry.EstimatorChoice`): an unknown key, a bad value or a
        missing package is an error naming the file and the key."""
        tbl = self.doc.get("estimator", {})
        if not isinstance(tbl, dict):
            raise self.error("estimator", "must be a table")
        kind = tbl.get("kind", DEFAULT_ESTIMATOR)
        if not isinstance(kind, str) or len(kind) > MAX_NAME_CHARS:
            raise self.error("estimator.kind", f"must be an estimator's name, got {value_repr(kind)}")
        for key in tbl:  # the kind checks its own keys, and says an unknown one whole
            if len(key) > MAX_NAME_CHARS:
                raise self.error(f"estimator.{_key_shown(key)}", "unknown key (longer than any name)")
        settings = {key: value for key, value in tbl.items() if key != "kind"}
        return EstimatorChoice(kind, settings, f"{self.where}: estimator")

    def spacecraft(self) -> SpacecraftParams:
        from hil.vscmg import geometry
        from hil.vscmg.params import inertia_tensor

        sc = self.table("spacecraft")
        preset = self.choice(sc, "spacecraft", "preset", _SPACECRAFT_PRESETS)
        builder = geometry.cubesat_1u if preset == "cubesat_1u" else geometry.air_bearing_testbed
        if "rotor_offset_m" in sc:
            offset = self.number(sc, "spacecraft", "rotor_offset_m", 0.0, positive=False)
            params = builder(rotor_offset_m=offset)
        else:
            params = builder()
        changes: dict[str, Any] = {}
        if "nominal_rotor_speed" in sc:
            changes["nominal_rotor_speed"] = self.number(sc, "spacecraft", "nominal_rotor_speed", 0.0)
        if "bus_inertia" in sc:
            raw = _numbers(sc["bus_inertia"])
            if raw is None or raw.shape not in ((3,), (3, 3)) or not np.all(np.isfinite(raw)):
                raise self.error(
                    "spacecraft.bus_inertia", "must be 3 diagonal values or a 3x3 matrix (kg m²)"
                )
            for element in raw.ravel():
                self.in_range("spacecraft", "bus_inertia", float(element))
            try:
                changes["bus_inertia"] = tuple(map(tuple, inertia_tensor(raw, "bus_inertia")))
            except ConfigError as exc:
                raise self.error("spacecraft.bus_inertia", exc.detail) from None
        units = self.array(params)
        if units is not None:
            changes["units"] = units
        try:
            return replace(params, **changes) if changes else params
        except ConfigError as exc:
            raise self.error("spacecraft", str(exc)) from None

    def array(self, params: SpacecraftParams) -> tuple[Any, ...] | None:
        from hil.vscmg import geometry

        arr = self.table("array")
        if not arr:
            return None
        kind = self.choice(arr, "array", "geometry", _GEOMETRIES)
        takes = _GEOMETRY_KEYS[kind]
        for key in arr:
            if key not in takes:  # dropped unsaid, it was an array other than the one written
                raise self.error(
                    f"array.{_key_shown(key)}",
                    f"not a key of geometry {value_repr(kind)}, which takes {', '.join(sorted(takes))}"
                    + ("" if "geometry" in arr else " (geometry not given: pyramid)"),
                )
        template = params.units[0]
        try:
            if kind == "pyramid":
                n = arr.get("units", 4)
                if not isinstance(n, int) or isinstance(n, bool) or not 2 <= n <= 8:
                    raise self.error("array.units", f"must be an integer 2..8, got {value_repr(n)}")
                skew_deg = self.number(arr, "array", "skew_deg", math.degrees(geometry.PYRAMID_BETA))
                if not MIN_SKEW_DEG <= skew_deg <= 90.0 - MIN_SKEW_DEG:
                    raise self.error(
                        "array.skew_deg",
                        f"must be within {MIN_SKEW_DEG:g}..{90 - MIN_SKEW_DEG:g} deg, got "
                        f"{value_repr(skew_deg)}: the pyramid degenerates towards 0 deg (gimbal axes "
                        "parallel) and 90 deg (coplanar)",
                    )
                skew = math.radians(skew_deg)
                return geometry.pyramid(n, skew, radius_m=0.025, height_m=-0.02, template=template)
            if kind == "tetrahedron":
                return geometry.tetrahedron(radius_m=0.12, height_m=0.05, template=template)
            for key in ("gimbal_axes", "spin_axes"):
                if key not in arr:
                    raise self.error(f"array.{key}", "required for a custom geometry")
            g = _numbers(arr["gimbal_axes"])
            if (
                g is None
                or g.ndim != 2
                or g.shape[1] != 3
                or not 1 <= len(g) <= 8
                or not np.all(np.isfinite(g))
            ):
                raise self.error("array.gimbal_axes", "must be 1..8 vectors of 3 finite numbers")
            for element in g.ravel():
                self.in_range("array", "gimbal_axes", float(element))
            s = self.vector(arr, "array", "spin_axes", g.shape)
            self._three_axis(g)
            try:
                return geometry.custom_array(g, s, template=template)
            except ConfigError as exc:
                raise self.error(
                    _CUSTOM_AXIS_KEYS.get(exc.where.rpartition(": ")[2], "array.custom"),
                    f"{exc.where.partition(': ')[0]}: {exc.detail}",
                ) from None
        except (ConfigError, ValueError) as exc:
            if isinstance(exc, ConfigError) and exc.where.startswith(self.where):
                raise
            raise self.error(f"array.{kind}", str(exc)) from None

    def _three_axis(self, gimbal_axes: np.ndarray) -> None:
        """A closed-loop run steers about three axes: a unit's torque (its gimbal's and its rotor's) lies in
        the plane across its gimbal axis, so the array has three-axis authority only if two of its gimbal
        axes are :data:`MIN_SKEW_DEG` or more apart (one unit, or units on parallel axes, turn the
        spacecraft about two axes at most: such a run "completed" 60-88 deg off), and as CMGs only with
        :data:`MIN_CUSTOM_UNITS` or more units."""
        lengths = np.linalg.norm(gimbal_axes, axis=1, keepdims=True)
        zero = np.flatnonzero(lengths.ravel() == 0.0)
        if zero.size:
            # divided by, it printed numpy's divide warnings, with this module's source lines, on the
            # user's terminal ahead of the error (the length of [1e-300, 0, 0] underflows to 0 too)
            raise self.error("array.gimbal_axes", f"unit {zero[0]}: a zero vector (axes are unit vectors)")
        g = gimbal_axes / lengths
        apart = max(
            (float(np.linalg.norm(np.cross(a, b))) for i, a in enumerate(g) for b in g[i + 1 :]), default=0.0
        )
        if apart < math.sin(math.radians(MIN_SKEW_DEG)):
            raise self.error(
                "array.gimbal_axes",
                f"the gimbal axes are all parallel (within {MIN_SKEW_DEG:g} deg): the array's torque lies in "
                "one plane, no three-axis control; give units on at least two axes apart",
            )
        if len(g) < MIN_CUSTOM_UNITS:
            raise self.error(
                "array.gimbal_axes",
                f"{len(g)} units: their gimbal torques span at most a plane at any gimbal angle, so the "
                "array is singular throughout (δ = det(D1 D1ᵀ) = 0, as for a pyramid of 2, refused); "
                f"give at least {MIN_CUSTOM_UNITS} units",
            )

    def sensors(self) -> PhoneSpec:
        sen = self.table("sensors")
        preset = self.choice(sen, "sensors", "preset", _SENSOR_PRESETS)
        phone = PhoneSpec.nexus5() if preset == "nexus5" else PhoneSpec.ideal()
        changes: dict[str, Any] = {}
        if "gravity" in sen:
            changes["gravity"] = self.number(sen, "sensors", "gravity", 9.81)
        if "field_enu_uT" in sen:
            f = self.vector(sen, "sensors", "field_enu_uT", (3,))
            if np.linalg.norm(f) < 1.0:
                raise self.error("sensors.field_enu_uT", "a field below 1 µT gives no heading")
            try:  # the estimator's check, here as the file is read (a run, or every run of a campaign, later)
                directions_matrix((0.0, 0.0, 1.0), f)
            except ConfigError:
                raise self.error(
                    "sensors.field_enu_uT", "parallel to gravity (a magnetic pole): no heading"
                ) from None
            changes["field_enu_uT"] = tuple(float(x) for x in f)
        for kind in ("gyr", "acc", "mag"):
            if kind not in sen:
                continue
            sub = self.table(f"sensors.{kind}", "sensors.*")
            base: SensorSpec = getattr(phone, kind)
            values = {}
            for key in sub:
                values[key] = self.number(sub, f"sensors.{kind}", key, 0.0, positive=key == "rate_hz")
                if values[key] < 0:
                    raise self.error(f"sensors.{kind}.{key}", "must not be negative")
            rate = values.get("rate_hz")
            if kind in NEEDED_SENSORS and rate is not None and rate < MIN_NEEDED_SENSOR_RATE_HZ:
                raise self.error(f"sensors.{kind}.rate_hz", needed_rate_error(kind, rate))
            try:
                changes[kind] = replace(base, **values)
            except ConfigError as exc:
                raise self.error(f"sensors.{kind}", exc.detail) from None
        phone = replace(phone, **changes) if changes else phone
        self.check_reading_range(phone, sen)
        return phone

    def check_reading_range(self, phone: PhoneSpec, sen: dict[str, Any]) -> None:
        """:func:`phone_out_of_range` as the file is read: the error names the field (or gravity) when it
        alone puts the phone out of range, else the sensor's larger figure of ``noise`` and ``bias`` when
        the file wrote it (the sensor's table when the preset's figure is the larger)."""
        found = phone_out_of_range(phone)
        if found is None:
            return
        key, detail = found
        kind, _, figure = key.partition(".")
        if figure and not (isinstance(sen.get(kind), dict) and figure in sen[kind]):
            key = kind
        raise self.error(f"sensors.{key}", detail)

    def controller(self) -> LoopConfig:
        c = self.table("controller")
        base = LoopConfig()
        gains = ControllerGains(
            natural_frequency=self.number(c, "controller", "natural_frequency", base.gains.natural_frequency),
            damping=self.number(c, "controller", "damping", base.gains.damping),
        )
        steering = SteeringParams(
            wheel_weight=self.number(c, "controller", "wheel_weight", base.steering.wheel_weight, False),
            mu=self.number(c, "controller", "mu", base.steering.mu, False),
            null_gain=self.number(c, "controller", "null_gain", base.steering.null_gain, False),
        )
        rate = self.number(c, "controller", "control_rate_hz", base.control_rate_hz)
        step = self.number(c, "controller", "plant_step_s", base.plant_step_s)
        warmup = self.number(c, "controller", "warmup_s", base.warmup_s, positive=False)
        try:
            return LoopConfig(
                plant_step_s=step,
                control_rate_hz=rate,
                frame_rate_hz=max(rate, base.frame_rate_hz),
                gains=gains,
                steering=steering,
                warmup_s=warmup,
            )
        except ConfigError as exc:
            raise self.error("controller", str(exc)) from None

    def manoeuvre(self, spacecraft: SpacecraftParams, duration_s: float) -> tuple[SlewScenario, float]:
        m = self.table("manoeuvre")

        def rotation(axis_key: str, angle_key: str, default_angle: float) -> np.ndarray:
            degrees = self.number(m, "manoeuvre", angle_key, default_angle, positive=False)
            if abs(degrees) > MAX_ANGLE_DEG:
                what = f"must be within ±{MAX_ANGLE_DEG:g} deg, got {value_repr(degrees)}"
                raise self.error(f"manoeuvre.{angle_key}", what)
            # an axis given is checked whether or not its angle turns about it: `initial_axis = "north"` (or
            # [nan, 0, 1]) without an initial_angle_deg was read as nothing and passed without a word
            axis = self.vector(m, "manoeuvre", axis_key, (3,)) if axis_key in m else np.array([0.0, 0.0, 1.0])
            angle = math.radians(degrees)
            if angle == 0.0:
                return np.eye(3)
            norm = float(np.linalg.norm(axis))
            if norm < 1e-9:
                raise self.error(f"manoeuvre.{axis_key}", "must not be the zero vector")
            return so3.exp(axis / norm * angle)

        R0 = rotation("initial_axis", "initial_angle_deg", 0.0)
        R_turn = rotation("axis", "angle_deg", 90.0)
        max_rate = self.number(m, "manoeuvre", "max_rate", 0.15)
        slew = SlewScenario(
            name="slew",
            R0=R0,
            R_target=R0 @ R_turn,  # the axis is in the body frame at the start
            duration_s=duration_s,
            max_rate=max_rate,
            max_accel=self.number(m, "manoeuvre", "max_accel", 0.025),
            gimbal_angle0=self.start_gimbal_angles(m, spacecraft, max_rate),
        )
        return slew, self.number(m, "manoeuvre", "settle_deg", 0.5)

    def start_gimbal_angles(
        self, m: dict[str, Any], spacecraft: SpacecraftParams, max_rate: float
    ) -> np.ndarray:
        """The gimbal angles (n,) rad the rotors spin up at: ``manoeuvre.gimbal_angles_deg``, else zeros
        where the rotors' momenta cancel there (a pyramid's, a tetrahedron's), else the zero-momentum
        angles nearest zero (:func:`zero_momentum_gimbal_angles`). The rotors spin up with the gimbals
        still, so the momentum they then carry goes into the bus (:func:`spin_up_rate`): angles at which
        it turns the spacecraft faster than the slew's own ``max_rate`` are refused, naming the key (a
        pyramid at 90 deg x 4 rolled at 5.6 rad/s, a custom x/y/z array at ~3 rad/s, and the runs
        "completed" 64-153 deg off); an array whose momenta cancel at no angle, naming
        ``array.spin_axes``."""
        n = spacecraft.n_units
        if "gimbal_angles_deg" in m:
            gimbals = np.radians(self.vector(m, "manoeuvre", "gimbal_angles_deg", (n,)))
            key = "manoeuvre.gimbal_angles_deg"
        else:
            gimbals = np.zeros(n)
            if not spin_up_momentum_cancels(spacecraft, gimbals):
                found = zero_momentum_gimbal_angles(spacecraft)
                gimbals = np.zeros(n) if found is None else found
            key = "array.spin_axes"
        momentum, rate = spin_up_rate(spacecraft, gimbals)
        speed = float(np.linalg.norm(rate))
        if speed > max_rate:
            degrees = ", ".join(f"{math.degrees(g):.4g}" for g in gimbals)
            advice = (
                "give gimbal angles at which the rotors' momenta cancel"
                if key.startswith("manoeuvre")
                else "no gimbal angles were found at which their momenta cancel: give spin axes that can, or "
                "manoeuvre.gimbal_angles_deg"
            )
            raise self.error(
                key,
                f"the rotors spin up at gimbal angles [{degrees}] deg with the gimbals still, carrying a net "
                f"momentum of {float(np.linalg.norm(momentum)):.3g} N m s, which turns the spacecraft at "
                f"{speed:.3g} rad/s, beyond the slew's max_rate {max_rate:g} rad/s before it starts "
                f"(the slew is rest-to-rest); {advice}",
            )
        return gimbals

    def options(self, name: str) -> dict[str, Any]:
        """A table of firmware-sim options: numbers, strings or lists of them."""
        tbl = self.table(name)
        for key, value in tbl.items():
            values = value if isinstance(value, list) else [value]
            if not values or not all(
                isinstance(v, int | float | str) and not isinstance(v, bool) for v in values
            ):
                raise self.error(
                    f"{name}.{key}", f"must be a number, a string or a list of them; got {value_repr(value)}"
                )
        return dict(tbl)


def _key_shown(key: str) -> str:
    """A TOML key as an error's ``where`` names it: whole up to :data:`MAX_NAME_CHARS` characters, else
    through :func:`~protocol.errors.value_repr` (a key of megabytes made a message of megabytes)."""
    return key if len(key) <= MAX_NAME_CHARS else value_repr(key)


def _seed_shown(seed: object) -> str:
    """A refused ``scenario.seed`` as the error says it: an integer spelled out whole, as the command
    line's ``--seed`` says it (the TOML loader holds integers within a float's range: at most 309 digits),
    anything else through :func:`~protocol.errors.value_repr`."""
    return str(seed) if isinstance(seed, int) and not isinstance(seed, bool) else value_repr(seed)


def _round_up(value: float, digits: int = 3) -> float:
    """``value`` (> 0) rounded up to ``digits`` significant figures: a least value said that rounding down
    would put back under its bound."""
    scale = 10.0 ** (math.floor(math.log10(value)) - digits + 1)
    return math.ceil(value / scale * (1.0 - 1e-12)) * scale


def _numbers(value: Any) -> np.ndarray | None:
    """``value`` (a number, or lists of them nested evenly) as a float array; None when any leaf is not a
    number — a string or a boolean, which numpy would read as one (``"2e-3"`` → 0.002, ``true`` → 1.0:
    ``field_enu_uT = [true, true, true]`` was a 1.7 µT field), as :meth:`number` refuses for a single
    value — or the lists are ragged."""

    def leaves(v: Any) -> bool:
        if isinstance(v, list):
            return all(leaves(x) for x in v)
        return isinstance(v, int | float) and not isinstance(v, bool)

    if not leaves(value):
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):  # ragged lists; an integer beyond a float
        return None
