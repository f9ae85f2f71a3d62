"""A control tick's record: its errors into the run's trace (from the slew's start) and its row into
``telemetry.csv``. The host hands over each tick what it saw and did as a :class:`TickSnapshot` — the
recorder holds no reference to the host — and the row is given by name to the run's column schema
(:class:`hil.runtime.telemetry.TelemetrySchema`), which lays it out in column order; the log's writer
thread formats it. A tick with a live board records the board's telemetry; a tick without one
(:class:`hil.runtime.faults.BoardLink` not live) records the estimates as ever, no board value at all, and
why and since when (``board_link``, ``tel_age_ms``)."""

from __future__ import annotations

import math
from array import array
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.control.attitude import Reference
from hil.runtime.phases import Phase
from hil.runtime.runlog import CsvLog, RowTap
from hil.runtime.telemetry import RunTrace, TelemetrySchema, angle_between9
from hil.runtime.watch import View
from hil.so3 import log_f, mat9
from hil.so3.floats import Mat9, Vec3
from protocol.messages import ActuatorSetpoint, Telemetry

Array = NDArray[np.float64]


@dataclass(slots=True)
class BoardReading:
    """The board as a tick with a live view of it saw it: its latest ``telemetry``, and from it the gimbal
    angles ``gimbal`` (n floats) rad and rotor speeds ``rotor`` (n floats) rad/s. (Not ``frozen``: made
    every tick, as :class:`TickSnapshot`.)"""

    telemetry: Telemetry
    gimbal: list[float]
    rotor: list[float]


@dataclass(slots=True)
class TickSnapshot:
    """What one control tick at host time ``t`` (s) saw and did, for its record; made by the host, read
    (never changed) by the recorder. Not ``frozen``: a frozen dataclass's ``__init__`` sets each field
    through ``object.__setattr__``, ~4 µs a tick for these 16 fields against ~0.5 µs (measured, Python
    3.11), on every control tick of every run.

    ``phase`` the run's phase after the tick's step; ``attitude`` body → inertial (a row-major 9-tuple)
    and ``rate`` (3 floats) rad/s the estimate (None before the estimator's first output);
    ``true_attitude`` / ``true_rate`` the simulation's truth (None on hardware); ``target9`` the target
    attitude as a row-major 9-tuple (None before the target is known); ``slew_start`` host s (None before
    the first slew); ``reference`` the moving reference the controller tracked (None when it did not
    steer); ``view`` the host's view of the board; ``phone_heard`` the host time (s) the phone's
    accepted-sample count last moved and ``phone_samples`` that count (the run's: 0, none yet).

    ``board`` is the live board (None: a blind tick, every board value empty); ``command`` the setpoint
    that went out (a blind tick: the hold setpoint in the tick it went out; None: nothing commanded);
    ``torque`` (3 floats) N m the controller's demand and ``delta`` the singularity measure δ at this tick's
    telemetry (None on a blind tick; ``torque`` None too when the controller did not run)."""

    t: float
    phase: Phase
    attitude: Mat9 | None
    rate: Vec3 | None
    true_attitude: Array | None
    true_rate: Array | None
    target9: Mat9 | None
    slew_start: float | None
    reference: Reference | None
    view: View
    phone_heard: float | None
    phone_samples: int
    board: BoardReading | None
    command: ActuatorSetpoint | None
    torque: Vec3 | None
    delta: float | None


class TickRecorder:
    """The rows (into ``log``, laid out by ``schema``; None keeps no rows: a Monte Carlo run) and the
    ``trace`` of one run, one :class:`TickSnapshot` at a time; the estimator's squared errors for its
    RMSE."""

    def __init__(self, schema: TelemetrySchema, log: CsvLog | RowTap | None, trace: RunTrace) -> None:
        self.schema = schema
        self.log = log
        self.trace = trace
        self._errors_sq = array("d")  # 8 bytes a tick from the slew's start (a list's float took ~32)

    def estimator_rmse(self) -> float | None:
        """The estimator's RMS attitude error (deg) from the slew's start over the ticks with a finite
        estimate (simulated runs), None without any."""
        return float(np.sqrt(np.mean(self._errors_sq))) if self._errors_sq else None

    def record(self, snap: TickSnapshot) -> None:
        """The tick's errors into the trace (from the slew's start) and its row into the telemetry log."""
        board = snap.board
        rates: list[float] = []
        if board is None:
            gimbal_rate = delta = math.nan
        else:
            rates = [u.gimbal_rate for u in board.telemetry.units]
            gimbal_rate = max(abs(r) for r in rates)
            assert snap.delta is not None  # a live tick always has the array's δ
            delta = snap.delta
        values = self._estimates(snap, gimbal_rate, delta)
        if values is None or self.log is None:
            return
        command = snap.command
        if command is not None:  # None: the operator has the run suspended, nothing commanded
            values["cmd_gimbal_rate"] = [u.gimbal for u in command.units]
            values["cmd_rotor_speed"] = [u.rotor_speed for u in command.units]
        if board is not None:
            values["tau"] = snap.torque
            values["delta"] = delta
            values["gimbal_angle"] = board.gimbal
            values["gimbal_rate"] = rates
            values["rotor_speed"] = board.rotor
            self._board_values(values, board.telemetry)
        values["tel_age_ms"] = None if snap.view.age_s is None else snap.view.age_s * 1e3
        values["board_link"] = int(snap.view.link)
        heard = snap.phone_heard
        values["phone_age_ms"] = None if heard is None or snap.phone_samples == 0 else (snap.t - heard) * 1e3
        self.log.write_values(self.schema.row(values))

    def _board_values(self, values: dict[str, Any], tel: Telemetry) -> None:
        """The board's own telemetry into ``values``: pulse widths (µs; empty for the pulses a board does
        not report), battery and UBEC in V and A, state and mode as their numbers, link counters."""
        n = self.schema.n_units
        pulses = list(tel.pulses_us[: 2 * n])
        values["pulse"] = pulses + [None] * (2 * n - len(pulses))
        values["battery_v"] = tel.battery_mv / 1000.0
        values["board_state"] = int(tel.state)
        values["link_rx_frames"] = tel.rx_frames
        values["link_bad_frames"] = tel.rx_bad
        values["link_age_ms"] = tel.link_age_ms
        values["battery_a"] = tel.battery_ma / 1000.0
        values["battery_soc"] = tel.battery_soc
        values["ubec_v"] = tel.ubec_mv / 1000.0
        values["ubec_a"] = tel.ubec_ma / 1000.0
        values["power_state"] = int(tel.power)
        values["watchdog"] = int(tel.watchdog)
        values["faults"] = tel.faults
        values["board_mode"] = int(tel.mode)

    def _estimates(self, snap: TickSnapshot, gimbal_rate: float, delta: float) -> dict[str, Any] | None:
        """The trace's tick (from the slew's start) and the row's first values (time .. rates, by block
        key); None when the run keeps no telemetry rows."""
        R_true = w_true = R_hat = w_hat = None
        if snap.true_attitude is not None:
            assert snap.true_rate is not None
            R_true = mat9(snap.true_attitude)
            w_true = tuple(np.asarray(snap.true_rate, dtype=float).tolist())
        if snap.attitude is not None:
            assert snap.rate is not None
            R_hat, w_hat = snap.attitude, snap.rate
        est_err = rate_err = None
        if R_true is not None and R_hat is not None:
            assert w_true is not None and w_hat is not None
            est_err = math.degrees(angle_between9(R_true, R_hat))
            rate_err = math.dist(w_hat, w_true)
            # from the slew's start, as the trace; a tick whose estimate is not a number counts as one
            # without an estimate (skipped): one NaN made the whole run's RMSE NaN, written as null — the
            # figure of every other tick lost (those ticks are the summary's ``unsteered_ticks``)
            if snap.slew_start is not None and math.isfinite(est_err):
                self._errors_sq.append(est_err * est_err)
        R_att = R_true if R_true is not None else R_hat
        point = track = None
        if R_att is not None and snap.target9 is not None:
            point = math.degrees(angle_between9(R_att, snap.target9))
            if snap.reference is not None:
                track = math.degrees(angle_between9(R_att, snap.reference.floats[0]))
        if snap.slew_start is not None:
            nan = math.nan
            self.trace.append(
                snap.t - snap.slew_start,
                nan if point is None else point,
                nan if track is None else track,
                nan if est_err is None else est_err,
                gimbal_rate,
                delta,
            )
        if self.log is None:
            return None
        return {
            "t": snap.t,
            "phase": int(snap.phase),
            "est_err_deg": est_err,
            "rate_err": rate_err,
            "point_err_deg": point,
            "track_err_deg": track,
            "est_r": None if R_hat is None else log_f(R_hat),
            "true_r": None if R_true is None else log_f(R_true),
            "est_w": w_hat,
            "true_w": w_true,
        }
