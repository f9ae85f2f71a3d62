"""Pulse outputs: the widths the firmware aims each channel at for its state, command and power stage,
and the optional PPM-sum train.

Channels alternate per unit: gimbal ``2·i``, rotor ``2·i + 1``. Widths come from each unit's calibration
(``UnitCalibration.gimbal_pulse_us``/``rotor_pulse_us``, the rotor's at the filtered battery voltage
rounded to 10 mV so conversions can be cached) as **fine widths** (1/512 µs,
:mod:`protocol.pulse_widths`), which the pulse stage dithers over frames in whole 0.5 µs ticks
(:class:`protocol.pulse_widths.SigmaDelta`). Disarmed or shedding load, every rotor gets
``rotor_safe_us``; in the LIMIT power stage rotor widths are capped at ``limit_throttle`` of their range.
A unit without calibration gets no gimbal pulse and a safe rotor. Whole-µs widths (the safe pulse, raw
pulses, an ESC endpoint) are whole ticks: they go out exactly, undithered.

A map's width is made a fine width by :func:`map_fine_width`, which clamps as the firmware's ``to_fine``
(``firmware/src/app.c``) does: a board must always output some pulse (``docs/calibration.md`` §1), and
the emulator used to raise ``FieldRangeError`` there instead, ending ``firmware-sim`` with a traceback.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from protocol.pulse_widths import FINE_MAX, FINE_PER_US, reported_us, whole_us

from .commands import Command
from .config import BoardConfig
from .timeline import PpmTrain

_VOLT_QUANTUM = 0.01  # V: pulse conversions are cached per 10 mV of battery voltage
_CACHE_ENTRIES = 4096


def map_fine_width(width_us: float) -> int:
    """A map's width (µs) as a fine width (1/512 µs, round half to even), clamped to 0..``FINE_MAX``
    (``PULSE_MAX_US``) exactly as the firmware's ``to_fine``: a board puts out a pulse whatever the width.
    The maps keep their pulses within 500..2500 µs (``protocol.calibration.maps``), so the clamp bounds
    only the rounding at a table's end; it is the last guard, not the rule. Maps convert to a finite
    width (their inputs are checked), so NaN cannot reach it."""
    return min(max(round(width_us * FINE_PER_US), 0), FINE_MAX)


def conversion_voltage(filtered_v_cell: float | None, cells: int, battery_v: float) -> float:
    """The battery voltage (V) rotor widths are computed at: the power manager's filtered per-cell voltage
    times the cells (the measured voltage before its first sample), rounded to 10 mV."""
    v = battery_v if filtered_v_cell is None else filtered_v_cell * cells
    return round(v / _VOLT_QUANTUM) * _VOLT_QUANTUM


class PulseShaper:
    """Turns commands into pulse widths, caching calibration conversions (cleared by :meth:`clear_cache`
    when a calibration changes)."""

    def __init__(self, config: BoardConfig) -> None:
        self.n_units = config.n_units
        self.rotor_safe_us = config.rotor_safe_us
        self.limit_throttle = config.power.thresholds.limit_throttle
        self._cache: dict[tuple[Any, ...], Any] = {}

    def clear_cache(self) -> None:
        self._cache.clear()

    def widths(
        self,
        calibrations: Sequence[Any | None],
        command: Command,
        *,
        armed: bool,
        raw_mode: bool,
        shed: bool,
        limit: bool,
        battery_v: float,
    ) -> tuple[tuple[int | None, ...], bool]:
        """(fine widths per channel, clamped): the firmware's pulse widths (1/512 µs; None: no pulse) for
        the present state (``armed``: motors enabled), control mode (``raw_mode``: RAW_PULSES), power stage
        (``shed``: rotors stopped, ``limit``: rotors capped) and ``command``; ``clamped`` is true when a
        setpoint had to be limited (a saturated conversion, or the LIMIT cap)."""
        safe = whole_us(self.rotor_safe_us)
        v = battery_v
        out: list[int | None] = []
        clamped = False
        raw = command.raw if (armed and raw_mode) else None
        for i in range(self.n_units):
            cal = calibrations[i]
            # gimbal channel
            if raw is not None:
                g: int | None = whole_us(raw[2 * i])
            elif cal is None:
                g = None
            else:
                conv = self._convert(cal, "g", command.gimbal[i], command.gimbal_mode)
                clamped |= conv.saturated and armed
                g = map_fine_width(conv.value)
            # rotor channel
            if not armed or shed:
                r: int | None = safe
            elif raw is not None:
                r = whole_us(raw[2 * i + 1])
            elif cal is None:
                r = safe
            else:
                conv = self._convert(cal, "r", command.rotor[i], v)
                clamped |= conv.saturated
                r = map_fine_width(conv.value)
            if armed and not shed and limit and cal is not None and r is not None:
                cap = self._rotor_cap(cal, v)
                if r > cap:
                    r = cap
                    clamped = True
            out.append(g)
            out.append(r)
        return tuple(out), clamped

    def _rotor_cap(self, cal: Any, v: float) -> int:
        """The LIMIT stage's highest rotor width (fine)."""
        lo = self._convert(cal, "r", 0.0, v).value
        hi = self._convert(cal, "r", 1e9, v).value
        return map_fine_width(lo + self.limit_throttle * (hi - lo))

    def _convert(self, cal: Any, kind: str, value: float, arg: Any) -> Any:
        key = (id(cal), kind, value, arg)
        hit = self._cache.get(key)
        if hit is None:
            if len(self._cache) > _CACHE_ENTRIES:
                self._cache.clear()
            if kind == "r":
                hit = cal.rotor_pulse_us(value, arg)
            else:
                hit = cal.gimbal_pulse_us(value, arg)
            self._cache[key] = hit
        return hit


def ppm_train(t_us: int, targets: Sequence[int | None], rotor_safe_us: int) -> PpmTrain:
    """The PPM-sum frame starting at ``t_us`` for the first 8 channels' fine widths, in whole µs (a PPM
    receiver resolves no finer; no pulse: the safe width)."""
    from protocol.pulses import clamp_ppm_width, encode_ppm  # optional output: imported on first use

    # Like a PPM output stage, limit each width to the PPM channel range (raw pulses may reach 500-2500).
    widths = [clamp_ppm_width(reported_us(w) if w else rotor_safe_us) for w in targets[:8]]
    train = encode_ppm(widths)
    return PpmTrain(t_us / 1e6, tuple(float(e) for e in train))
