"""Verification sweeps: command setpoints through the maps a board holds and measure how well the units
track them.

:func:`run_verify` arms the board in SETPOINT mode and holds, for every verified unit at once, a few
setpoints of each map (:class:`VerifyPlan`): rotor speeds at fractions of the full-throttle speed at the
present battery voltage (``KV·V``), gimbal rates at fractions of the map's top rate each way, gimbal
angles at fractions of the angle range (in ANGLE mode). Each point waits for the response to settle,
averages the dwell, and reports the tracking error (measured − commanded) against its tolerance:
``rotor_tolerance`` of the full speed, ``gimbal_rate_tolerance_rad_s``, ``gimbal_angle_tolerance_rad``.
The guard of the sweeps applies.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from protocol.calibration import UnitCalibration
from protocol.errors import ConfigError, ProtocolError
from protocol.messages import BoardState, ControlMode, GimbalMode, Telemetry, UnitSetpoint

from .bench import BenchKind
from .benchlink import BenchLink, Guard, GuardTripped, Settling, check_tolerance, hold
from .progress import Eta, Report, no_report


@dataclass(frozen=True)
class VerifyPlan:
    """The points (fractions, see the module docstring), their settling and the tolerances."""

    rotor_fractions: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8)
    gimbal_rate_fractions: tuple[float, ...] = (-0.6, -0.3, 0.3, 0.6)
    gimbal_angle_fractions: tuple[float, ...] = (-0.5, 0.0, 0.5)
    settling: Settling = field(default_factory=lambda: Settling(settle_s=0.5))
    rotor_tolerance: float = 0.02  # of KV·V
    gimbal_rate_tolerance_rad_s: float = 0.05
    gimbal_angle_tolerance_rad: float = 0.03
    guard: Guard = field(default_factory=Guard)

    def __post_init__(self) -> None:
        _check_fractions(self.rotor_fractions, 0.0, "VerifyPlan.rotor_fractions")
        _check_fractions(self.gimbal_rate_fractions, -1.0, "VerifyPlan.gimbal_rate_fractions")
        _check_fractions(self.gimbal_angle_fractions, -1.0, "VerifyPlan.gimbal_angle_fractions")
        check_tolerance(self.rotor_tolerance, "--rotor-tolerance")
        check_tolerance(self.gimbal_rate_tolerance_rad_s, "--rate-tolerance")
        check_tolerance(self.gimbal_angle_tolerance_rad, "--angle-tolerance")
        moving = [abs(f) for f in self.rotor_fractions if f != 0.0]
        if moving and not self.rotor_tolerance < min(moving):  # known before any board: refused at once
            raise ConfigError(
                f"{self.rotor_tolerance!r} of full speed is not below the smallest verification point, "
                f"{min(moving):g}: {_STILL_PASSES}",
                TOLERANCE_OPTIONS[BenchKind.ROTOR],
            )


def _check_fractions(fractions: tuple[float, ...], lowest: float, where: str) -> None:
    """Refuse (:class:`ConfigError` naming the point) verification points that are not numbers in
    [``lowest``, 1]: the fraction of a map's range a point commands. Refused with the plan, before any
    board is armed: NaN reached the armed board as a NaN setpoint after the points before it had run, and a
    point past the map's range (a rotor at 3× full speed, a gimbal at twice its top rate or beyond its
    angle span) was clamped by the map, so a unit that tracked every command it could take FAILed it."""
    if not isinstance(fractions, tuple | list) or not fractions:
        raise ConfigError(f"{fractions!r} must be one or more fractions of the map's range", where)
    for i, f in enumerate(fractions):
        if isinstance(f, bool) or not isinstance(f, int | float) or not lowest <= f <= 1.0:
            raise ConfigError(f"{f!r} is no fraction of the map's range in [{lowest:g}, 1]", f"{where}[{i}]")


TOLERANCE_OPTIONS = {
    BenchKind.ROTOR: "--rotor-tolerance",
    BenchKind.GIMBAL_RATE: "--rate-tolerance",
    BenchKind.GIMBAL_ANGLE: "--angle-tolerance",
}
"""The option that sets each map's verification tolerance."""

_STILL_PASSES = "a unit that never moves would pass that point"
"""Why a tolerance as large as a point's motion is refused."""


def check_tolerances_tell_motion(
    kinds: tuple[BenchKind, ...], calibrations: Mapping[int, UnitCalibration], plan: VerifyPlan
) -> None:
    """Refuse (:class:`ConfigError` naming the option) a tolerance that passes a unit that does not follow
    its commands: a gimbal rate tolerance at least a point's rate (a still gimbal is within it there), an
    angle tolerance at least half the gap between two points' angles (a gimbal stuck at one is within it at
    the next). ``--rotor-tolerance 1`` passed every rotor point of a stopped rotor, ``--rate-tolerance
    1e160`` every gimbal point. The gimbal maps' targets come from the units' calibrations (the rotor's are
    fractions of full speed: checked by the plan itself)."""
    if BenchKind.GIMBAL_RATE in kinds:
        for f in plan.gimbal_rate_fractions:
            targets, tolerances = _targets(BenchKind.GIMBAL_RATE, f, calibrations, plan, volts=1.0)
            for unit, target in targets.items():
                if target != 0.0 and not tolerances[unit] < abs(target):
                    raise ConfigError(
                        f"{tolerances[unit]!r} rad/s is not below unit {unit}'s gimbal rate at {f:+.0%} of "
                        f"its range, {abs(target):.4g} rad/s: {_STILL_PASSES}",
                        TOLERANCE_OPTIONS[BenchKind.GIMBAL_RATE],
                    )
    if BenchKind.GIMBAL_ANGLE in kinds:
        for unit, cal in calibrations.items():
            angles = sorted({_angle_target(cal, f) for f in plan.gimbal_angle_fractions})
            gaps = [b - a for a, b in zip(angles, angles[1:], strict=False)]
            if gaps and not plan.gimbal_angle_tolerance_rad < min(gaps) / 2:
                raise ConfigError(
                    f"{plan.gimbal_angle_tolerance_rad!r} rad is not below half unit {unit}'s smallest gap "
                    f"between verification angles, {min(gaps) / 2:.4g} rad: a gimbal stuck at one would "
                    "pass the next",
                    TOLERANCE_OPTIONS[BenchKind.GIMBAL_ANGLE],
                )


@dataclass(frozen=True)
class VerifyPoint:
    """One unit at one setpoint: commanded and measured (rad/s or rad), the error and its tolerance."""

    unit: int
    kind: BenchKind
    commanded: float
    measured: float
    tolerance: float
    settled: bool

    @property
    def error(self) -> float:
        return self.measured - self.commanded

    @property
    def ok(self) -> bool:
        return abs(self.error) <= self.tolerance

    def line(self) -> str:
        unit = "rad" if self.kind is BenchKind.GIMBAL_ANGLE else "rad/s"
        flag = "ok" if self.ok else "FAIL"
        settle = "" if self.settled else " (unsettled)"
        return (
            f"unit {self.unit} {self.kind.value:<12} commanded {self.commanded:9.4f} {unit:<5} measured "
            f"{self.measured:9.4f}  error {_small(self.error, '+8.4f')} "
            f"(tolerance {_small(self.tolerance, '.4f')}) {flag}{settle}"
        )


def _small(x: float, spec: str) -> str:
    """``x`` in ``spec`` (fixed point: the table's columns line up), or to 3 significant digits where that
    would show a non-zero number as 0 (a tolerance of 1e-05 printed ``0.0000``)."""
    text = format(x, spec)
    if x != 0 and float(text) == 0:
        return format(x, "+.3g" if spec.startswith("+") else ".3g")
    return text


@dataclass(frozen=True)
class VerifyReport:
    points: tuple[VerifyPoint, ...]

    @property
    def ok(self) -> bool:
        return all(p.ok for p in self.points)

    def for_unit(self, unit: int) -> list[VerifyPoint]:
        return [p for p in self.points if p.unit == unit]

    def table(self) -> str:
        return "\n".join(p.line() for p in self.points)


def run_verify(
    link: BenchLink,
    calibrations: Mapping[int, UnitCalibration],
    plan: VerifyPlan,
    kinds: tuple[BenchKind, ...] | Mapping[int, tuple[BenchKind, ...]] = tuple(BenchKind),
    *,
    report: Report = no_report,
) -> VerifyReport:
    """Verify the units of ``calibrations`` (the sets the board holds for them) on the maps ``kinds``: the
    same for every unit, or per unit (a unit verifies the maps its run changed; each point holds the
    units that verify that map, the others at rest). The outputs are put back to rest afterwards
    (Disarm); a tripped guard raises :class:`GuardTripped`. ``report`` gets one line per point with the
    time left."""
    for unit in calibrations:
        link.check_unit(unit)
    per_unit = kinds if isinstance(kinds, Mapping) else dict.fromkeys(calibrations, kinds)
    fractions = {
        BenchKind.ROTOR: plan.rotor_fractions,
        BenchKind.GIMBAL_RATE: (*plan.gimbal_rate_fractions, 0.0),  # 0: the hold pulse must hold
        BenchKind.GIMBAL_ANGLE: plan.gimbal_angle_fractions,
    }
    verifying = {k: {u: c for u, c in calibrations.items() if k in per_unit.get(u, ())} for k in BenchKind}
    order = [k for k in BenchKind if verifying[k]]
    for kind in order:
        check_tolerances_tell_motion((kind,), verifying[kind], plan)
    eta = Eta(sum(len(fractions[k]) for k in order))
    points: list[VerifyPoint] = []
    link.check_board("the time before verification")  # a board that reset since holds other sets
    try:
        first = link.prepare(ControlMode.SETPOINT, GimbalMode.RATE)
        volts = first.battery_mv / 1000.0
        link.client.arm()
        for kind in order:
            for f in fractions[kind]:
                targets, tol = _targets(kind, f, verifying[kind], plan, volts)
                done = _point(link, plan, kind, targets, tol)
                points += done
                eta.step()
                worst = max(done, key=lambda p: abs(p.error) - p.tolerance)
                report(
                    f"verify {eta.text()}: {kind.value} at {f:+.0%}, worst unit {worst.unit} error "
                    f"{_small(worst.error, '+.4f')} (tolerance {_small(worst.tolerance, '.4f')}) "
                    f"{'ok' if worst.ok else 'FAIL'}"
                )
    finally:
        link.safe()
    return VerifyReport(tuple(points))


def _targets(
    kind: BenchKind,
    fraction: float,
    calibrations: Mapping[int, UnitCalibration],
    plan: VerifyPlan,
    volts: float,
) -> tuple[dict[int, float], dict[int, float]]:
    """Each unit's setpoint for ``fraction`` of ``kind``'s range and its tolerance (rad/s or rad)."""
    if kind is BenchKind.ROTOR:
        full = {u: c.rotor.kv_rad_s_per_v * volts for u, c in calibrations.items()}
        return {u: fraction * full[u] for u in calibrations}, {
            u: plan.rotor_tolerance * full[u] for u in full
        }
    if kind is BenchKind.GIMBAL_RATE:
        targets = {u: _rate_target(c, fraction) for u, c in calibrations.items()}
        return targets, dict.fromkeys(calibrations, plan.gimbal_rate_tolerance_rad_s)
    targets = {u: _angle_target(c, fraction) for u, c in calibrations.items()}
    return targets, dict.fromkeys(calibrations, plan.gimbal_angle_tolerance_rad)


def _rate_target(cal: UnitCalibration, fraction: float) -> float:
    lo, hi = cal.gimbal_rate.rate_range
    return fraction * (hi if fraction > 0 else -lo)


def _angle_target(cal: UnitCalibration, fraction: float) -> float:
    ys = cal.gimbal_angle.curve.y
    lo, hi = min(ys), max(ys)
    return 0.5 * (lo + hi) + fraction * 0.5 * (hi - lo)


_FIELD = {
    BenchKind.ROTOR: "rotor_speed",
    BenchKind.GIMBAL_RATE: "gimbal_rate",
    BenchKind.GIMBAL_ANGLE: "gimbal_angle",
}


def _point(
    link: BenchLink,
    plan: VerifyPlan,
    kind: BenchKind,
    targets: Mapping[int, float],
    tolerances: Mapping[int, float],
) -> list[VerifyPoint]:
    """Hold ``targets`` (unit → value) on every verified unit; the others stay at rest."""
    n = link.info.n_units
    mode = GimbalMode.ANGLE if kind is BenchKind.GIMBAL_ANGLE else GimbalMode.RATE
    rest = link.latest() if mode is GimbalMode.ANGLE else None
    units: list[UnitSetpoint] = []
    for u in range(n):
        gimbal = rest.units[u].gimbal_angle if rest is not None else 0.0
        rotor = 0.0
        if u in targets and kind is BenchKind.ROTOR:
            rotor = targets[u]
        elif u in targets:
            gimbal = targets[u]
        units.append(UnitSetpoint(gimbal, rotor))
    attr = _FIELD[kind]
    order = list(targets)

    def check() -> None:
        link.check_board(f"verification ({kind.value})")
        for tel in link.telemetry:
            why = plan.guard.check(tel)
            if why is not None:
                raise GuardTripped(f"{why} during verification")
            if tel.state is not BoardState.ARMED:
                raise ProtocolError(f"the board left ARMED ({tel.state.name}) during verification")

    def watched(tel: Telemetry) -> list[float]:
        return [getattr(tel.units[u], attr) for u in order]

    tol_settle = {
        BenchKind.ROTOR: 0.3,
        BenchKind.GIMBAL_RATE: 0.004,
        BenchKind.GIMBAL_ANGLE: 0.002,
    }[kind]
    dwell, settled = hold(
        link,
        send=lambda: link.setpoint(mode, units),
        ready=lambda tel: tel.state is BoardState.ARMED,
        watched=watched,
        tolerance=lambda i, value: tol_settle + 0.0005 * abs(value),
        settling=plan.settling,
        check=check,
    )
    m = len(dwell)
    return [
        VerifyPoint(
            unit=u,
            kind=kind,
            commanded=targets[u],
            measured=sum(getattr(t.units[u], attr) for t in dwell) / m,
            tolerance=tolerances[u],
            settled=settled,
        )
        for u in order
    ]
