"""An upload for a unit whose calibration download is running is NACKed ``BUSY`` until the download has
ended, and every fragment of the download, retries included, is of the set the request found — for every
target (docs/protocol.md, "Calibration transfers").

The firmware once re-read the live set at every retry (``report.c``: ``report_cal_fragment``), so an
upload during a download mixed two sets in one transfer and, the new set being shorter, read past its
end (``len - start`` underflowed); the emulator sent the snapshot taken at the request. Both ends now
refuse the upload of that unit while its download runs.

Drawn: the unit, the new set's size, and when the upload comes (before the first retry or among them).
"""

from __future__ import annotations

import random

import pytest

from conformance.host import heartbeat
from protocol.calibration import EscMotorModel, GimbalServoModel, Reassembler, fragment
from protocol.calibration.unit import UnitCalibration
from protocol.crc import crc16_ccitt_false
from protocol.messages import Ack, CalibrationData, CalibrationRequest, Log, Nack, NackReason

TRANSFER = 7


def _new_set(knots: int) -> bytes:
    m, g = EscMotorModel(), GimbalServoModel()
    return UnitCalibration(
        m.rotor_map(knots=knots), g.rate_map(knots_per_side=3), g.angle_map(knots=3)
    ).to_bytes()


@pytest.mark.parametrize("draw", range(2))
def test_an_upload_waits_for_the_download_of_its_unit(target, host, draw):
    rng = random.Random(draw)
    unit = rng.randrange(target.spec.n_units)
    new = _new_set(rng.choice([4, 8, 16]))
    wait = rng.uniform(0.0, 0.3)  # the board resends every 0.1 s, five tries in all
    why = f"{target.name}: unit {unit}, a new set of {len(new)} bytes, uploaded {wait * 1000:.0f} ms in"
    host.handshake()
    host.keepalive = heartbeat
    start = len(host.received)
    assert isinstance(host.request(CalibrationRequest(unit=unit, transfer_id=TRANSFER)), Ack), why
    host.poll(wait)
    parts = fragment(unit, 3, new)
    answer = host.request(parts[0])  # the download's fragments are not ACKed: it runs on
    assert isinstance(answer, Nack) and answer.reason == NackReason.BUSY, (why, answer)
    host.poll(0.8)  # the download is given up after its fifth try
    got = [m for m in host.received[start:] if isinstance(m, CalibrationData) and m.transfer_id == TRANSFER]
    assert got, why
    first = got[0]
    head = (unit, first.count, first.total_len, first.set_crc)
    assert all((m.unit, m.count, m.total_len, m.set_crc) == head for m in got), why
    by_index = {m.index: m for m in got}
    assert sorted(by_index) == list(range(first.count)), why
    assert all(bytes(m.chunk) == bytes(by_index[m.index].chunk) for m in got), why  # a retry is the same
    reasm = Reassembler()
    done = [reasm.feed(by_index[i]) for i in range(first.count)][-1]
    assert done is not None and crc16_ccitt_false(done[1]) == first.set_crc, why
    assert any(isinstance(m, Log) and "abandoned" in m.text for m in host.received[start:]), why
    # the download has ended: the upload goes through
    assert all(isinstance(host.request(p), Ack) for p in parts), why
