"""Dead-ESC detection: an output commanded to move that shows no response for ``dead_esc_detect_s`` is
reported once per channel per boot (``Log`` DEAD_ESC, fault flag DEAD_ESC).

A rotor is suspect when the speed its pulse stands for is above 10 % of rated and it turns below 5 % of
that; a gimbal (RATE mode only) when it is asked more than 0.1 rad/s and moves below 10 % of it.
"""

from __future__ import annotations

from collections.abc import Sequence

from protocol.messages import GimbalMode, Severity

from ..actuators import UnitModel
from ..config import BoardConfig
from .codes import LogCode
from .telemetry import Outbox


class DeadEscDetector:
    """``found``: the channels reported since the last reset."""

    def __init__(self, config: BoardConfig, outbox: Outbox) -> None:
        self.detect_s = config.dead_esc_detect_s
        self.rated_speed_rad_s = config.motor.rated_speed_rad_s
        self.found: set[int] = set()
        self._since: list[float | None] = [None] * config.n_channels
        self._out = outbox

    def reset(self) -> None:
        self._since = [None] * len(self._since)
        self.found.clear()

    def check(
        self,
        t: int,
        outputs: Sequence[float | None],
        units: Sequence[UnitModel],
        battery_v: float,
        gimbal_mode: GimbalMode,
    ) -> None:
        """Compare each unit's response at ``t`` (µs) with what ``outputs`` (the mean widths, µs) command at
        ``battery_v``."""
        now = t / 1e6
        v = battery_v
        rated = self.rated_speed_rad_s
        rate_mode = gimbal_mode is GimbalMode.RATE
        since = self._since
        for i, unit in enumerate(units):
            g_ch, r_ch = 2 * i, 2 * i + 1
            rotor_us = outputs[r_ch]
            expected = 0.0 if rotor_us is None else unit.rotor_speed_for(rotor_us, v)
            rotor_bad = expected > 0.1 * rated and abs(unit.rotor_speed) < 0.05 * expected
            gimbal_us = outputs[g_ch]
            if gimbal_us is None or not rate_mode:
                gimbal_bad = False
            else:
                want = abs(unit.gimbal_value_for(gimbal_us, GimbalMode.RATE))
                gimbal_bad = want > 0.1 and abs(unit.gimbal_rate) < 0.1 * want
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
