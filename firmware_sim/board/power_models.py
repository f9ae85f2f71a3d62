"""Power: a LiPo battery (OCV curve, internal resistance → sag, coulomb-counted state of charge), a UBEC
rail with a current limit, and the staged power manager (warn → limit → shed → brown-out).

The loads are constant-power (ESCs and the buck converter draw whatever current their power needs), so the
battery terminal voltage solves ``V = Voc − R·P/V``: ``V = (Voc + √(Voc² − 4RP)) / 2``. Past the pack's
maximum power (``Voc² < 4RP``) the voltage collapses to ``Voc/2`` — the MCU browns out long before.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

from protocol.messages import PowerState

from .config import BatteryParams, PowerThresholds, UbecParams


@dataclass
class PowerReading:
    """One sample of the power system (volts, amps, SoC 0..1)."""

    battery_v: float = 0.0
    battery_a: float = 0.0
    soc: float = 1.0
    ubec_v: float = 0.0
    ubec_a: float = 0.0
    ubec_overcurrent: bool = False


class Battery:
    """State of charge by coulomb counting; terminal voltage from the OCV curve and internal resistance.

    ``sag_v`` and ``extra_resistance_ohm`` are set by fault injection (a cold or damaged pack)."""

    def __init__(self, params: BatteryParams) -> None:
        self.params = params
        self.soc = params.initial_soc
        self.sag_v = 0.0
        self.extra_resistance_ohm = 0.0
        self._soc_pts = [s for s, _ in params.ocv_curve]
        self._v_pts = [v for _, v in params.ocv_curve]
        self._segment = self._segment_at(params.initial_soc)  # the SoC's, kept: it moves rarely

    def ocv(self) -> float:
        """Open-circuit pack voltage (V), fault sag included, never below 0."""
        # Asked at every physics step: the clamps spelt out, the curve searched only when the SoC left
        # the last segment.
        s = self.soc
        if s < 0.0:
            s = 0.0
        elif s > 1.0:
            s = 1.0
        s0, s1, v0, v1 = self._segment
        if not s0 <= s < s1:
            s0, s1, v0, v1 = self._segment = self._segment_at(s)
        cell = v0 + (v1 - v0) * (s - s0) / (s1 - s0)
        v = cell * self.params.cells - self.sag_v
        return 0.0 if v < 0.0 else v

    def _segment_at(self, s: float) -> tuple[float, float, float, float]:
        """(SoC, SoC, V, V) at the ends of the OCV curve's segment that holds ``s`` (0..1)."""
        pts = self._soc_pts
        i = min(max(bisect.bisect_right(pts, s) - 1, 0), len(pts) - 2)
        return pts[i], pts[i + 1], self._v_pts[i], self._v_pts[i + 1]

    @property
    def resistance(self) -> float:
        return self.params.internal_resistance_ohm + self.extra_resistance_ohm

    def terminal(self, power_w: float) -> tuple[float, float]:
        """(volts, amps) at the terminals while loads draw ``power_w`` watts."""
        voc = self.ocv()
        if power_w <= 0.0 or voc <= 0.0:
            return voc, 0.0
        disc = voc * voc - 4.0 * self.resistance * power_w
        v = voc / 2.0 if disc <= 0.0 else (voc + math.sqrt(disc)) / 2.0
        return v, power_w / v if v > 0 else 0.0

    def discharge(self, amps: float, dt: float) -> None:
        soc = self.soc - amps * dt / (self.params.capacity_mah * 3.6)
        self.soc = 0.0 if soc < 0.0 else soc  # max(soc, 0.0), at every physics step


def ubec_output(params: UbecParams, battery_v: float, load_a: float) -> tuple[float, float, bool]:
    """(rail volts, rail amps, overcurrent) of the UBEC feeding ``load_a`` amps at its set voltage.

    Past the current limit the output folds back to ``set · limit / load`` (constant current into the
    load); it can never exceed the battery voltage minus the regulator's dropout."""
    v = params.set_voltage_v
    over = load_a > params.current_limit_a
    if over:
        v *= params.current_limit_a / load_a
    ceiling = battery_v - params.dropout_v
    if ceiling < v:  # min() and max() spelt out: solved twice at every physics step
        v = ceiling
    if 0.0 > v:
        v = 0.0
    amps = load_a * v / params.set_voltage_v if params.set_voltage_v > 0 else 0.0
    return v, amps, over


def ubec_input_power(params: UbecParams, rail_v: float, rail_a: float) -> float:
    """Watts the UBEC draws from the battery to deliver ``rail_v · rail_a``."""
    return rail_v * rail_a / params.efficiency


# Stages looked up once (an enum member's lookup costs about 60 ns; the manager samples at 200 Hz).
_NORMAL, _BROWN_OUT = PowerState.NORMAL, PowerState.BROWN_OUT


class PowerManager:
    """The staged thresholds, on a low-pass filtered battery voltage (per cell), with hysteresis.

    ``update(v_battery, dt)`` returns the stage. WARN/LIMIT/SHED follow the filtered voltage; the board
    latches SHED itself (rotors stay stopped until a new ``Arm``). BROWN_OUT is the MCU's own detector on
    the UBEC rail, checked by the board with :meth:`browned_out`.
    """

    def __init__(self, thresholds: PowerThresholds, cells: int) -> None:
        self.t = thresholds
        self.cells = cells
        self.filtered_v_cell: float | None = None
        self.state = PowerState.NORMAL
        self._levels = (  # highest stage first
            (PowerState.SHED, thresholds.shed_v_cell),
            (PowerState.LIMIT, thresholds.limit_v_cell),
            (PowerState.WARN, thresholds.warn_v_cell),
        )

    def reset(self) -> None:
        self.filtered_v_cell = None
        self.state = PowerState.NORMAL

    def update(self, battery_v: float, dt: float) -> PowerState:
        v_cell = battery_v / self.cells
        f = self.filtered_v_cell
        tau = self.t.filter_time_constant_s
        if f is None or tau <= 0.0:
            f = v_cell
        else:
            f += (v_cell - f) * (1.0 - math.exp(-dt / tau))
        self.filtered_v_cell = f
        self.state = self._stage(f)
        return self.state

    def _stage(self, v: float) -> PowerState:
        hysteresis = self.t.hysteresis_v_cell
        current = self.state if self.state is not _BROWN_OUT else _NORMAL
        for stage, level in self._levels:
            # Enter below the level; stay in a stage already reached until hysteresis above it.
            if v < level or (current >= stage and v < level + hysteresis):
                return stage
        return _NORMAL

    def browned_out(self, rail_v: float) -> bool:
        return rail_v < self.t.brownout_v

    def released(self, rail_v: float) -> bool:
        return rail_v >= self.t.brownout_release_v
