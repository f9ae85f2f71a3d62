"""Calibration transfers between the host and the board's EEPROM.

Upload (``CalibrationData`` fragments, DISARMED only): reassembled, parsed and validated as the unit's
calibration class, then stored (it survives resets). Download (``CalibrationRequest``): the stored set is
sent as ``CalibrationData`` fragments, each resent every 0.1 s until the host ACKs it and abandoned after
5 tries; one download at a time. An upload for the unit being downloaded is NACKed ``BUSY`` until the
download has ended (the firmware resends a download's fragments from the stored set itself).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from protocol.calibration import Reassembler, default_unit_calibration, fragment
from protocol.errors import HilError
from protocol.messages import (
    Ack,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    Nack,
    NackReason,
    Severity,
)

from .codes import LogCode
from .link import BoardLink
from .telemetry import Outbox

_RETRY_US = 100_000  # µs between resends of an unacknowledged download fragment (0.1 s)
_TRIES = 5


def calibration_or_default(calibrations: Sequence[Any | None], unit: int) -> Any:
    """The unit's stored calibration, or the default set where it has none."""
    cal = calibrations[unit]
    return cal if cal is not None else default_unit_calibration()


class CalibrationTransfers:
    """Uploads into ``calibrations`` (one entry per unit, ``None``: not calibrated) through ``store(unit,
    cal)``, and downloads from it on ``link``."""

    def __init__(
        self,
        calibrations: Sequence[Any | None],
        link: BoardLink,
        outbox: Outbox,
        store: Callable[[int, Any], None],
    ) -> None:
        self.calibrations = calibrations
        self.link = link
        self._out = outbox
        self._store = store
        self._reassembler = Reassembler()
        self._pending: dict[int, list[Any]] = {}  # seq -> [message, tries, next_retry_us]

    def reset(self) -> None:
        """MCU reset: a partial upload and an unfinished download are forgotten."""
        self._reassembler = Reassembler()
        self._pending.clear()

    def new_session(self) -> None:
        """A compatible Hello: uploads of the earlier session are forgotten, finished ones too (a restarted
        host numbers its transfers from 1 again: its set must not pass for a repeat of an old one)."""
        self._reassembler.forget()

    # ------------------------------------------------------------------ upload
    def upload(self, msg: CalibrationData, state: BoardState) -> NackReason | None:
        """One upload fragment; returns None (accepted) or the NACK reason."""
        if state is not BoardState.DISARMED:
            return NackReason.BAD_STATE
        if msg.unit >= len(self.calibrations):
            return NackReason.OUT_OF_RANGE
        if any(entry[0].unit == msg.unit for entry in self._pending.values()):
            return NackReason.BUSY  # the firmware resends a download from the set itself: it must not change
        try:
            done = self._reassembler.feed(msg)
        except (HilError, ValueError) as exc:
            return self._refused(msg.unit, exc)
        if done is None:
            return None
        unit, data = done
        cal_type = type(calibration_or_default(self.calibrations, unit))
        try:
            cal = cal_type.from_bytes(data, source=f"upload unit {unit}")
        except (HilError, ValueError) as exc:
            # refused after reassembly: forgotten, so the same set sent again is judged (and refused)
            # again, not acknowledged as a repeat of a set taken
            self._reassembler.forget()
            return self._refused(unit, exc)
        self._store(unit, cal)
        self._out.log(
            Severity.INFO, LogCode.CALIBRATION, f"calibration for unit {unit} stored ({len(data)} bytes)"
        )
        return None

    def _refused(self, unit: int, exc: Exception) -> NackReason:
        self._out.log(
            Severity.ERROR, LogCode.CALIBRATION, f"calibration upload for unit {unit} refused: {exc}"
        )
        return NackReason.BAD_CALIBRATION

    # ------------------------------------------------------------------ download
    def download(self, msg: CalibrationRequest, state: BoardState, t: int) -> NackReason | None:
        """Start sending the unit's set at ``t`` (µs); returns None (accepted) or the NACK reason."""
        if state is BoardState.BOOT:
            return NackReason.BAD_STATE
        if msg.unit >= len(self.calibrations):
            return NackReason.OUT_OF_RANGE
        cal = self.calibrations[msg.unit]
        if cal is None:
            return NackReason.BAD_CALIBRATION
        if self._pending:
            return NackReason.BUSY
        for part in fragment(msg.unit, msg.transfer_id, cal.to_bytes()):
            seq = self.link.send(part)
            if seq is not None:
                self._pending[seq] = [part, 1, t + _RETRY_US]
        return None

    @property
    def next_retry_us(self) -> float:
        """Board time (µs) of the next resend (inf: nothing pending)."""
        if not self._pending:  # the usual case, asked at every board event
            return math.inf
        return min(entry[2] for entry in self._pending.values())

    def retry_due(self, t: int) -> None:
        """Resend every fragment due at ``t`` (µs); give up the download after the last try — once: the
        loop stops there, as the firmware's does (it walked the rest of its copy of the pending fragments
        after giving up, logging the abandonment once for each)."""
        if not self._pending:  # the usual case, at every main-loop pass
            return
        for seq, entry in list(self._pending.items()):
            if entry[2] <= t:
                self._retry(seq, entry, t)
                if not self._pending:  # given up
                    return

    def _retry(self, seq: int, entry: list[Any], t: int) -> None:
        if entry[1] >= _TRIES:
            self._pending.clear()
            self._out.log(
                Severity.ERROR,
                LogCode.CALIBRATION,
                f"calibration download abandoned: no ACK after {_TRIES} tries",
            )
            return
        entry[1] += 1
        entry[2] = t + _RETRY_US
        self.link.send(entry[0], seq=seq)

    def on_answer(self, msg: Ack | Nack) -> None:
        """The host's ACK/NACK of a download fragment (any other answer is counted as ignored)."""
        if msg.msg_id != CalibrationData.MSG_ID or msg.seq not in self._pending:
            self.link.stats.ignored += 1
            return
        if isinstance(msg, Nack):
            self._pending.clear()
            self._out.log(
                Severity.WARNING, LogCode.CALIBRATION, f"host refused calibration fragment: {msg.reason.name}"
            )
            return
        del self._pending[msg.seq]
