"""Scenarios: one TOML file says everything a closed-loop run needs — the spacecraft and its VSCMG array,
the phone's sensors, the estimator and controller, the board and its faults, and the manoeuvre.

A scenario is looked up by name in ``fixtures/scenarios/`` (``cubesat-1u`` → ``cubesat-1u.toml``) or read
from a path. Every table and key is optional except ``[scenario] name``; what is left out takes the
defaults below. Unknown keys are errors (a typo must not silently become a default), and every error names
the file and the dotted key (:class:`ConfigError` ``where="cubesat-1u.toml: manoeuvre.angle_deg"``).
Every number has documented bounds (:data:`hil.scenario.reader.RANGES`: e.g. ``plant_step_s`` 10 µs..1 ms,
``warmup_s`` 0..600 s, sensor rates 1..1000 Hz), and a run is at most a day of simulated time (warm-up and
duration) and 10⁸ plant steps. The phone must read within what the host admits of a phone's sensors (its
field, gravity, and 5 σ of each sensor's bias and noise: :data:`hil.scenario.reader.READING_SIGMAS`).
The file is at most 16 MiB, nested at most 32 deep, and holds no integer
beyond a float's range (±1.8e308; :mod:`hil.files.bounded`).

```toml
[scenario]
name = "cubesat-1u"            # required
description = "..."
duration_s = 40.0              # from the start of the slew (warm-up comes first)
seed = 1                       # sensor noise and biases (0..2⁶³−1)

[spacecraft]
preset = "cubesat_1u"          # or "air_bearing_testbed"
rotor_offset_m = 0.5e-3        # σ, every unit
nominal_rotor_speed = 400.0    # rad/s
bus_inertia = [2e-3, 2.1e-3, 2.2e-3]   # kg m², diagonal or 3x3 (replaces the preset's); refused when
                               # too small for the rotors' momentum: the bus would carry the gimbals away
                               # from their servos (reader.GIMBAL_COUPLING_MARGIN; the error says the least)

[array]                        # replaces the preset's geometry (its unit template is kept)
geometry = "pyramid"           # "pyramid" | "tetrahedron" | "custom"
units = 4
skew_deg = 54.74
gimbal_axes = [[...], ...]     # custom only, body frame
spin_axes = [[...], ...]       # custom only, at zero gimbal angle

[sensors]                      # the phone on the spacecraft (defaults: a Nexus 5)
preset = "nexus5"              # or "ideal"
gravity = 9.81
field_enu_uT = [0.0, 27.0, -38.0]
[sensors.gyr]                  # also acc, mag: any of rate_hz, noise, bias, jitter_s, offset_s
rate_hz = 200.0

[estimator]                    # hil.estimation.registry; `hil run --estimator NAME` picks another
kind = "variational"           # the default; or "vqf" (pip install vqf), or an installed package's
preset = "paper"               # variational: or "tuned"
# tau_acc_s = 3.0              # vqf: tau_acc_s, tau_mag_s, motion_bias, rest_bias, mag_rejection

[controller]
control_rate_hz = 50.0         # ≤ board.frame_rate
plant_step_s = 0.001           # the world's step (≤ 1 ms)
natural_frequency = 0.7        # rad/s
damping = 0.9
null_gain = 0.5                # steering null motion (1/s)
wheel_weight = 2.0
mu = 10.0
warmup_s = 2.0                 # hold still first: the estimator converges, the gyro bias is measured

[board]                        # firmware-sim's options, as on its command line
frame_rate = 50.0
telemetry_rate = 50.0          # ≥ 8 Hz: two frames per 0.25 s, the age the host sees the board stale at
link_timeout = 0.25

[faults]                       # firmware-sim's fault options, times from the board's start
stall = ["12:1.0"]             # link stall at 12 s for 1 s
corrupt = 0.001

[manoeuvre]                    # a rest-to-rest eigenaxis slew
axis = [1.0, 2.0, 2.0]
angle_deg = 90.0                # deg, within ±180 (flown the short way)
max_rate = 0.15                # rad/s
max_accel = 0.025              # rad/s²
initial_axis = [0, 0, 1]       # the start attitude (default: identity)
initial_angle_deg = 0.0
gimbal_angles_deg = [0, 0, 0, 0]   # where the rotors spin up (default: zeros, or where a custom array's
                               # momenta cancel); refused if the spin-up turns the bus faster than max_rate
settle_deg = 0.5               # the requirement the summary checks
```
"""

from __future__ import annotations

from pathlib import Path

from hil.files.bounded import MAX_DOCUMENT_BYTES, load_toml
from protocol.errors import ConfigError, HilError

from .model import Scenario
from .paths import FIXTURES, read_text, resolve_named_file
from .reader import _Reader

SCENARIO_DIR = FIXTURES / "scenarios"
DEFAULT_SCENARIO = "cubesat-1u"


def scenario_names() -> list[str]:
    """The scenarios shipped in ``fixtures/scenarios``."""
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A path as given, or the shipped scenario of that name; :class:`ConfigError` listing the names
    (:func:`~hil.scenario.paths.resolve_named_file`)."""
    return resolve_named_file(name_or_path, SCENARIO_DIR, "scenario", "scenario")


def load_scenario(name_or_path: str | Path = DEFAULT_SCENARIO) -> Scenario:
    """Read and check a scenario (see the module docstring); any error is a :class:`ConfigError` naming
    the file and key."""
    path = resolve_scenario_path(name_or_path)
    return parse_scenario(read_text(path, limit=MAX_DOCUMENT_BYTES), path)


def parse_scenario(text: str, path: Path | None = None) -> Scenario:
    """:func:`load_scenario` on TOML text (``path`` only names the source in errors)."""
    where = path.name if path is not None else "<scenario>"
    doc = load_toml(text, where)
    reader = _Reader(doc, where)
    try:
        return reader.scenario(text, path)
    except ConfigError:
        raise
    except HilError as exc:  # a value the parts refused (e.g. a jitter above the sample period)
        raise ConfigError(str(exc), where) from exc


__all__ = [
    "DEFAULT_SCENARIO",
    "SCENARIO_DIR",
    "Scenario",
    "load_scenario",
    "parse_scenario",
    "resolve_scenario_path",
    "scenario_names",
]
