"""A control tick's record: its errors into the run's trace (from the slew's start) and its row into
``telemetry.csv`` — plain values in column order (:mod:`hil.runtime.telemetry`), formatted by the log's
writer thread. A tick with a live board records the board's telemetry; a tick without one
(:class:`hil.runtime.faults.BoardLink` not live) records the estimates as ever, no board value at all, and
why and since when (``board_link``, ``tel_age_ms``)."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from hil.control.attitude import Reference
from hil.runtime.telemetry import angle_between9
from hil.runtime.watch import View
from hil.so3 import log_f, mat9
from protocol.messages import ActuatorSetpoint, Telemetry

if TYPE_CHECKING:
    from hil.runtime.host import Array, Host


class TickRecorder:
    """The rows and trace of one :class:`~hil.runtime.host.Host` (which it reads: estimate, truth, phase,
    target, the slew's start); the estimator's squared errors for its RMSE."""

    def __init__(self, host: Host) -> None:
        self.host = host
        self._errors_sq: list[float] = []
        self._none3 = (None, None, None)

    def estimator_rmse(self) -> float | None:
        """The estimator's RMS attitude error (deg) from the slew's start (simulated runs), None without."""
        return float(np.sqrt(np.mean(self._errors_sq))) if self._errors_sq else None

    def live(
        self, t: float, tel: Telemetry, view: View, gimbal: Array, rotor: Array,
        command: ActuatorSetpoint | None, cmd_out: Any, ref: Reference | None,
    ) -> None:  # fmt: skip
        """The tick's errors into the trace (from the slew's start) and its row into the telemetry log:
        plain floats in column order (:mod:`hil.runtime.telemetry`), formatted by the log's writer thread."""
        if cmd_out is not None:  # steering computed δ from this telemetry already
            delta = float(cmd_out[1].delta[0])
        else:
            delta = float(self.host.steering.delta(gimbal, rotor)[0])
        rates = [u.gimbal_rate for u in tel.units]
        row = self._estimates(t, ref, max(abs(r) for r in rates), delta)
        if row is None:
            return
        n = self.host.n
        none3 = self._none3
        row += none3 if cmd_out is None else cmd_out[0].torque.tolist()
        row.append(delta)
        row += gimbal.tolist()
        row += rates
        row += rotor.tolist()
        if command is None:  # the operator has the run suspended: nothing commanded
            row += [None] * (2 * n)
        else:
            row += [u.gimbal for u in command.units]
            row += [u.rotor_speed for u in command.units]
        pulses = list(tel.pulses_us[: 2 * n])
        row += pulses + [None] * (2 * n - len(pulses))
        row += [tel.battery_mv / 1000.0, int(tel.state), tel.rx_frames, tel.rx_bad, tel.link_age_ms]
        row += [tel.battery_ma / 1000.0, tel.battery_soc, tel.ubec_mv / 1000.0, tel.ubec_ma / 1000.0,
                int(tel.power), int(tel.watchdog), tel.faults, int(tel.mode)]  # fmt: skip
        row += self._view_cells(t, view)
        self.host.telemetry.write_values(row)  # type: ignore[union-attr]  # None: _estimates returned None

    def blind(self, t: float, view: View, hold: ActuatorSetpoint | None) -> None:
        """A tick without a live view of the board: the estimates as ever, every board value empty, and
        why (``board_link``) and since when (``tel_age_ms``); the hold setpoint, in the tick it went out."""
        row = self._estimates(t, None, math.nan, math.nan)
        if row is None:
            return
        n = self.host.n
        row += self._none3 + (None,)  # torque demand, δ
        row += [None] * (3 * n)  # gimbal angles, rates, rotor speeds
        if hold is not None:
            row += [u.gimbal for u in hold.units] + [u.rotor_speed for u in hold.units]
        else:
            row += [None] * (2 * n)
        row += [None] * (2 * n + 5 + 8)  # pulses, battery .. link age, the board's extras
        row += self._view_cells(t, view)
        self.host.telemetry.write_values(row)  # type: ignore[union-attr]

    def _view_cells(self, t: float, view: View) -> list[Any]:
        host = self.host
        heard = host.phone_heard
        return [
            None if view.age_s is None else view.age_s * 1e3,
            int(view.link),
            None if heard is None or host.phone_count == 0 else (t - heard) * 1e3,
        ]

    def _estimates(
        self, t: float, ref: Reference | None, gimbal_rate: float, delta: float
    ) -> list[Any] | None:
        """The trace's tick (from the slew's start) and the row's first cells (time .. rates); None when
        the run keeps no telemetry rows."""
        host = self.host
        truth = host.truth()
        est = host.estimate
        none3 = self._none3
        R_true = w_true = R_hat = w_hat = None
        if truth is not None:
            R_true, w_true = mat9(truth.R), tuple(np.asarray(truth.omega, dtype=float).tolist())
        if est is not None:
            R_hat, w_hat = mat9(est.R), tuple(np.asarray(est.omega, dtype=float).tolist())
        est_err = rate_err = None
        if R_true is not None and R_hat is not None:
            assert w_true is not None and w_hat is not None
            est_err = math.degrees(angle_between9(R_true, R_hat))
            rate_err = math.dist(w_hat, w_true)
            if host.slew_start is not None:  # from the slew's start, as the trace
                self._errors_sq.append(est_err * est_err)
        R_att = R_true if R_true is not None else R_hat
        point = track = None
        if R_att is not None and host.target9 is not None:
            point = math.degrees(angle_between9(R_att, host.target9))
            if ref is not None:
                track = math.degrees(angle_between9(R_att, mat9(ref.R)))
        if host.slew_start is not None:
            nan = math.nan
            host.trace.append(
                t - host.slew_start, nan if point is None else point, nan if track is None else track,
                nan if est_err is None else est_err, gimbal_rate, delta,
            )  # fmt: skip
        if host.telemetry is None:
            return None
        row: list[Any] = [t, int(host.phase), est_err, rate_err, point, track]
        row += none3 if R_hat is None else log_f(R_hat)
        row += none3 if R_true is None else log_f(R_true)
        row += none3 if w_hat is None else w_hat
        row += none3 if w_true is None else w_true
        return row
