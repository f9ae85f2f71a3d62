"""What an attitude estimator is to the rest of the host: the :class:`Estimator` protocol the run's host,
its warm-up, ``hil replay`` and the Monte Carlo campaigns call, the :class:`Site` it is built for, and the
:class:`EstimatorKind` a package implements to add one (registered by name in
:mod:`hil.estimation.registry`, chosen by a scenario's ``[estimator] kind`` or ``--estimator NAME``).

Two estimators come with the project: ``variational`` (:class:`hil.estimation.filter.AttitudeFilter`, the
paper's estimator with its pre-filter and measurement handling; the default) and ``vqf``
(:mod:`hil.estimation.vqf_adapter`, a thin adapter over the ``vqf`` package). Pure interfaces, no I/O.

Units and frames, for every estimator: merged steps (:class:`~hil.estimation.sensors.MergedStep`) carry
time ``t`` (s, the phone's clock), the step ``h`` (s), gyroscope (rad/s), accelerometer (m/s², gravity
included) and magnetometer (µT; only its direction need matter) readings in the phone's body frame, None
(live) or NaN with a stale flag (batch) for a sensor that is not usable. Estimates are body → ENU (true
north), their rate in the body frame (rad/s)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from hil.estimation.estimator import Estimate, EstimateBatch
    from hil.estimation.sensors import MergedStep, MergedSteps

Array = NDArray[np.float64]


@runtime_checkable
class Estimator(Protocol):
    """An attitude estimator over merged steps, live and in batch.

    :meth:`step` and :meth:`run` continue from the same state and should give the same numbers; the host
    steps it live, ``hil replay`` runs it in batch (or live with ``--paced``)."""

    def step(self, s: MergedStep) -> Estimate:
        """Take one merged step (``s.h`` s after the previous one; ignored on the first) and return the
        estimate at ``s.t``: ``R`` (3, 3) body → ENU, ``omega`` (3,) rad/s the body rate estimate,
        ``omega_err`` (3,) rad/s what the estimator takes off the bias-corrected gyro (zero for one that
        takes nothing off), ``flags`` (:class:`~hil.estimation.sensors.StepFlag`: the step's own ``|``
        the estimator's), ``iterations`` (solver iterations; 0 for a closed-form step). ValueError for a
        step that is not after the previous one."""
        ...

    def run(self, steps: MergedSteps, progress: Callable[[int, int], None] | None = None) -> EstimateBatch:
        """Every merged step in ``steps`` (N; ``steps.t`` strictly increasing, after the last step
        taken), continuing from the current state: ``t`` (N,) s, ``R`` (N, 3, 3), ``omega`` and
        ``omega_err`` (N, 3) rad/s, ``flags`` and ``iterations`` (N,). ``progress(done, total)`` is called
        now and then (after the last step at least)."""
        ...

    @property
    def gyro_bias(self) -> Array:
        """The gyro bias estimate b̂ (3,), rad/s: what is taken off the gyroscope's readings."""
        ...

    def set_gyro_bias(self, bias: ArrayLike) -> None:
        """Continue from the gyro bias ``bias`` (3,) rad/s, measured while running (the host's still
        window averages the raw gyroscope): ConfigError for one that is not a finite 3-vector."""
        ...

    def set_rest_learning(self, enabled: bool) -> None:
        """Let the estimator learn the gyro bias when it finds the phone at rest, or not, from the next
        step on. The host turns it off once the spacecraft moves under control: a slew's slow end or a
        hold turns steadily below any rest detector's bound, and would be learnt as bias. An estimator
        without rest learning does nothing."""
        ...


@dataclass(frozen=True)
class Site:
    """Where the phone is and what is known before the first step, as an estimator needs it.

    ``field_enu`` (3,): the geomagnetic field in ENU, true north (only its direction is used: any unit);
    ``declination_deg``: its declination (east of true north, degrees), kept as given so that an estimator
    working in magnetic north need not recompute it; ``magnetometer``: False for a log without one
    (6-axis: heading unobserved); ``gyro_bias`` (3,) rad/s: the initial gyro bias estimate (e.g. a still
    window's mean gyro); ``init``: the initial attitude, ``"measured"`` (from the first measurements) or
    a (3, 3) body → ENU matrix; ``sample_period_s``: the merged steps' nominal period (s; the fastest
    sensor's), for an estimator whose gains are set for a fixed rate."""

    field_enu: tuple[float, float, float]
    declination_deg: float
    sample_period_s: float
    magnetometer: bool = True
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    init: Literal["measured"] | Array = "measured"

    @classmethod
    def of_field(cls, field_enu: ArrayLike, sample_period_s: float, **known: Any) -> Site:
        """The site of a field vector ``field_enu`` (3,) in ENU (a scenario's phone)."""
        f = np.asarray(field_enu, dtype=float).reshape(3)
        declination = math.degrees(math.atan2(f[0], f[1]))
        field = (float(f[0]), float(f[1]), float(f[2]))
        return cls(field, declination, sample_period_s, **known)

    @classmethod
    def of_dip(
        cls, inclination_deg: float, declination_deg: float, sample_period_s: float, **known: Any
    ) -> Site:
        """The site of a field with this inclination (down from horizontal) and declination (degrees): its
        unit direction ``(cos i sin d, cos i cos d, −sin i)`` in ENU (a recorded log)."""
        i, d = math.radians(inclination_deg), math.radians(declination_deg)
        field = (math.cos(i) * math.sin(d), math.cos(i) * math.cos(d), -math.sin(i))
        return cls(field, declination_deg, sample_period_s, **known)


class EstimatorKind(Protocol):
    """One kind of estimator, as the registry knows it: its settings' keys and checks, and how to build
    one for a site. A package adds one by an entry point in the group ``vscmg_hil.estimators``
    (:mod:`hil.estimation.registry`)."""

    name: str
    """What a scenario's ``[estimator] kind`` and ``--estimator`` call it."""

    keys: frozenset[str]
    """The settings a scenario's ``[estimator]`` table may give it (besides ``kind``)."""

    def check(self, settings: Mapping[str, Any], where: str) -> dict[str, Any]:
        """``settings`` (a subset of :attr:`keys`, as read from TOML) checked and completed with the
        defaults; ConfigError naming ``where: estimator.KEY`` for a bad value, or a missing dependency."""
        ...

    def build(self, settings: Mapping[str, Any], site: Site) -> Estimator:
        """A fresh estimator with these (checked) settings for ``site``."""
        ...

    def describe(self, settings: Mapping[str, Any]) -> str:
        """One line for a run's or a replay's setup: the estimator and its settings."""
        ...
