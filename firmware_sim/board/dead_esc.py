"""Dead-ESC detection: an output commanded to move that shows no response for ``dead_esc_detect_s`` is
reported once per channel per boot (``Log`` DEAD_ESC, fault flag DEAD_ESC).

A rotor is suspect when the speed its pulse stands for is above 10 % of rated and it turns below 5 % of
that; a gimbal (RATE mode only) when it is asked more than 0.1 rad/s and moves below 10 % of it. The
rotor channel the ESC endpoint procedure drives (:mod:`.esc_calibration`) is not checked while it runs:
its ESC sees the high endpoint unpowered (waiting for its supply) or in its programming mode, where it
beeps and turns nothing — what the procedure expects, not a dead ESC (it was once reported as one, an
ERROR in every emulated calibration).
"""

from __future__ import annotations

from collections.abc import Sequence

from protocol.messages import GimbalMode, Severity
from protocol.pulse_widths import FINE_PER_US

from .actuators import UnitModel
from .codes import LogCode
from .config import BoardConfig
from .telemetry import Outbox
from .volts import TenMillivolts


class DeadEscDetector:
    """``found``: the channels reported since the last reset."""

    def __init__(self, config: BoardConfig, outbox: Outbox) -> None:
        self.detect_s = config.dead_esc_detect_s
        self.rated_speed_rad_s = config.motor.rated_speed_rad_s
        self.found: set[int] = set()
        self._since: list[float | None] = [None] * config.n_channels
        self._out = outbox
        # The speeds below which each unit's rotor and gimbal count as not responding, for the outputs,
        # voltage (10 mV) and gimbal mode they were worked out for: the outputs change at the pulse
        # frames, the check runs with every power sample (see :meth:`_floors`).
        self._floors_for: tuple[Sequence[int | None], float, GimbalMode] | None = None
        self._floor_values: list[tuple[float | None, float | None]] = []
        self._volts = TenMillivolts()  # round(v, 2), asked at every power sample

    def reset(self) -> None:
        self._since = [None] * len(self._since)
        self.found.clear()

    def forget(self) -> None:
        """A calibration changed: what a pulse stands for is worked out anew."""
        self._floors_for = None

    def check(
        self,
        t: int,
        targets: Sequence[int | None],
        units: Sequence[UnitModel],
        battery_v: float,
        gimbal_mode: GimbalMode,
        being_taught: int | None = None,
    ) -> None:
        """Compare each unit's response at ``t`` (µs) with what the firmware's ``targets`` (fine widths,
        1/512 µs) command at ``battery_v``; channel ``being_taught`` (its ESC's endpoints: not expected to
        turn) counts as responding."""
        now = t / 1e6
        since = self._since
        for i, (rotor_floor, gimbal_floor) in enumerate(self._floors(targets, units, battery_v, gimbal_mode)):
            unit = units[i]
            g_ch, r_ch = 2 * i, 2 * i + 1
            rotor_bad = (
                rotor_floor is not None and abs(unit.rotor_speed) < rotor_floor and r_ch != being_taught
            )
            gimbal_bad = gimbal_floor is not None and abs(unit.gimbal_rate) < gimbal_floor
            if not (gimbal_bad or rotor_bad) and since[g_ch] is None and since[r_ch] is None:
                continue  # the usual case: both respond, neither was suspect
            for ch, bad in ((g_ch, gimbal_bad), (r_ch, rotor_bad)):
                if not bad:
                    since[ch] = None
                    continue
                since_ch = since[ch]
                if since_ch is None:
                    since[ch] = now
                elif now - since_ch >= self.detect_s and ch not in self.found:
                    self.found.add(ch)
                    kind = "gimbal" if ch % 2 == 0 else "rotor"
                    self._out.log(
                        Severity.ERROR,
                        LogCode.DEAD_ESC,
                        f"{kind} ESC on channel {ch} (unit {ch // 2}) not responding",
                    )

    def _floors(
        self,
        targets: Sequence[int | None],
        units: Sequence[UnitModel],
        battery_v: float,
        gimbal_mode: GimbalMode,
    ) -> list[tuple[float | None, float | None]]:
        """Per unit, (rotor, gimbal) speed below which it does not respond to ``targets`` (None: not
        asked enough to tell). Rotor speeds are converted at ``battery_v`` to 10 mV (``rotor_speed_for``),
        so the floors hold while the same targets tuple (a pulse frame sets a new one) and the same 10 mV
        step last."""
        volts = self._volts(battery_v)
        held = self._floors_for
        if held is not None and held[0] is targets and held[1] == volts and held[2] is gimbal_mode:
            return self._floor_values
        outputs = [None if q is None else q / FINE_PER_US for q in targets]  # mean widths, µs
        rated = self.rated_speed_rad_s
        floors: list[tuple[float | None, float | None]] = []
        for i, unit in enumerate(units):
            rotor_us, gimbal_us = outputs[2 * i + 1], outputs[2 * i]
            expected = 0.0 if rotor_us is None else unit.rotor_speed_for(rotor_us, battery_v)
            rotor_floor = 0.05 * expected if expected > 0.1 * rated else None
            gimbal_floor = None
            if gimbal_us is not None and gimbal_mode is GimbalMode.RATE:
                want = abs(unit.gimbal_value_for(gimbal_us, GimbalMode.RATE))
                gimbal_floor = 0.1 * want if want > 0.1 else None
            floors.append((rotor_floor, gimbal_floor))
        self._floors_for, self._floor_values = (targets, volts, gimbal_mode), floors
        return floors
