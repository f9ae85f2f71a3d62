"""What a phone is, as a scenario states it: its three sensors' rates, noise, bias and timestamp jitter
(:class:`SensorSpec`), and the gravity and geomagnetic field around it (:class:`PhoneSpec`). The host tunes
its estimator from these; the world's simulated phone (:mod:`firmware_sim.world.models.phone`) samples by
them.

Default figures (:meth:`PhoneSpec.nexus5`), per axis, and where they come from:

- rates 198.6 / 198.6 / 49.6 Hz (gyroscope / accelerometer / magnetometer): measured on the LG Nexus 5
  logs of ``shared/data/tyrex-nexus5`` (the paper's rate-mismatch case); start offsets of a few ms.
- gyroscope noise 1.7e-3 rad/s per sample: InvenSense MPU-6500-family (the Nexus 5's MPU-6515) noise
  density 0.01 °/s/√Hz over its ~92 Hz bandwidth; residual bias 5e-3 rad/s (0.3 °/s) after Android's
  gyroscope calibration (the uncalibrated zero-rate offset is ±5 °/s; the tyrex raw logs show the OS's
  bias estimates of 0.005–0.07 rad/s).
- accelerometer noise 0.03 m/s² per sample: 300 µg/√Hz over ~92 Hz (same part); bias 0.05 m/s².
- magnetometer noise 0.4 µT, residual hard-iron bias 1 µT after calibration (AKM AK8963 class, 0.15 µT
  resolution).
- timestamp jitter 0.1 ms (gyroscope, accelerometer) and 0.2 ms (magnetometer), 1-σ.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hil.estimation.params import PAPER_E
from hil.estimation.sensors import SensorKind
from protocol.errors import ConfigError

MIN_RATE_HZ = 1.0
"""The slowest a phone sensor may sample (Hz), as a scenario's ``sensors.*.rate_hz`` (a dispersion drew
5e-324 Hz: a magnetometer that never sampled, and the runs said ok)."""


@dataclass(frozen=True)
class SensorSpec:
    """One sensor: ``rate_hz``; per-axis white ``noise`` and constant ``bias`` standard deviations (in the
    sensor's unit); timestamp ``jitter_s`` (1-σ, s) and the first sample's ``offset_s``."""

    rate_hz: float
    noise: float
    bias: float
    jitter_s: float = 1e-4
    offset_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("rate_hz", "noise", "bias", "jitter_s", "offset_s"):
            # -0.0 passes ">= 0" but numpy's samplers refuse it as a scale ("scale < 0"): held as 0.0
            object.__setattr__(self, name, getattr(self, name) + 0.0)
        if not (self.rate_hz >= MIN_RATE_HZ and self.noise >= 0 and self.bias >= 0 and self.jitter_s >= 0):
            raise ConfigError(
                f"invalid sensor figures {self!r} (a rate of {MIN_RATE_HZ:g} Hz or more; noise, bias and "
                "jitter >= 0)",
                "SensorSpec",
            )
        if self.jitter_s * 4 >= 1.0 / self.rate_hz:
            raise ConfigError(
                "timestamp jitter must stay well below the sample period", "SensorSpec.jitter_s"
            )


@dataclass(frozen=True)
class PhoneSpec:
    """A phone's three sensors and its environment: ``gravity`` (m/s²), ``field_enu_uT`` (3,) the
    geomagnetic field in ENU (µT)."""

    gyr: SensorSpec = field(default_factory=lambda: SensorSpec(198.6, 1.7e-3, 5e-3, 1e-4, 0.0))
    acc: SensorSpec = field(default_factory=lambda: SensorSpec(198.6, 0.03, 0.05, 1e-4, 0.0021))
    mag: SensorSpec = field(default_factory=lambda: SensorSpec(49.6, 0.4, 1.0, 2e-4, 0.0047))
    gravity: float = 9.81
    field_enu_uT: tuple[float, float, float] = tuple(47.0 * np.array(PAPER_E)[:, 1])  # type: ignore[assignment]

    @classmethod
    def nexus5(cls) -> PhoneSpec:
        """The defaults: Nexus-5-like rates and noise, the paper's field direction at 47 µT."""
        return cls()

    @classmethod
    def ideal(cls) -> PhoneSpec:
        """Noise-, bias- and jitter-free sensors at the same rates (for checking the filter's arithmetic)."""
        zero = {"noise": 0.0, "bias": 0.0, "jitter_s": 0.0}
        base = cls()
        return cls(
            SensorSpec(base.gyr.rate_hz, offset_s=base.gyr.offset_s, **zero),
            SensorSpec(base.acc.rate_hz, offset_s=base.acc.offset_s, **zero),
            SensorSpec(base.mag.rate_hz, offset_s=base.mag.offset_s, **zero),
        )

    def spec(self, kind: SensorKind) -> SensorSpec:
        return {SensorKind.GYR: self.gyr, SensorKind.ACC: self.acc, SensorKind.MAG: self.mag}[kind]
