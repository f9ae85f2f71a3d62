"""A calibration set the board refused is refused again when sent again, and a Hello forgets the earlier
session's transfers — for every target.

Both boards once acknowledged a refused set's repeat (found by review): the reassembler marked a transfer
complete as soon as its fragments and CRC checked (``link.c``: ``reasm_feed``; ``protocol.calibration``:
``Reassembler``), before the board judged the set (``app.c``: ``on_calibration_data``;
``firmware_sim.board.calibration``: ``CalibrationTransfers.upload``) and refused it (an invalid set, or
no room for it), so the same set sent again — a restarted host does exactly that: its transfer ids start
at 1 again — was taken for a harmless repeat of a completed transfer: every fragment ACKed, nothing
stored, no Log. A set refused after reassembly is now forgotten, and so is every transfer at a Hello (an
unfinished one from before a host's restart made the new host's first fragment of another set with the
same id "contradict its transfer").

Drawn: the invalid rotor KV, the transfer id, whether a Hello comes between the attempts. The answers
(ACK or NACK and its reason) and the board's calibration Logs are what is judged.
"""

from __future__ import annotations

import math
import random
import struct

import pytest

from conformance.host import heartbeat
from protocol.calibration import EscMotorModel, GimbalServoModel, fragment, model_unit_calibration
from protocol.crc import crc16_ccitt_false
from protocol.messages import Ack, Log, Nack, NackReason

CALIBRATION = 10  # LogCode.CALIBRATION
KV_AT = slice(16, 20)  # the rotor's KV (float32) in a set's bytes


def _good(kv: float) -> bytes:
    return model_unit_calibration(
        EscMotorModel(low_us=1050.0, high_us=1950.0, deadband_us=20.0, kv_rad_s_per_v=kv),
        GimbalServoModel(center_us=1520.0, max_rate_rad_s=1.5, direction=-1),
    ).to_bytes()


def _with_kv(data: bytes, kv: float) -> bytes:
    """``data`` with its KV replaced and its CRC made right again: valid framing, an invalid set."""
    out = bytearray(data)
    out[KV_AT] = struct.pack("<f", kv)
    out[-2:] = struct.pack("<H", crc16_ccitt_false(bytes(out[:-2])))
    return bytes(out)


def _upload(host, data: bytes, transfer_id: int, unit: int = 0) -> list:
    return [host.request(part) for part in fragment(unit, transfer_id, data)]


def _calibration_logs(host, start: int, words: str) -> list[Log]:
    host.poll(0.05)
    return [
        m for m in host.received[start:] if isinstance(m, Log) and m.code == CALIBRATION and words in m.text
    ]


def _refused(answers: list) -> bool:
    *first, last = answers
    return (
        all(isinstance(a, Ack) for a in first)
        and isinstance(last, Nack)
        and last.reason == NackReason.BAD_CALIBRATION
    )


@pytest.mark.parametrize("draw", range(3))
def test_a_refused_set_sent_again_is_refused_again(target, host, draw):
    rng = random.Random(draw)
    bad_kv = rng.choice([0.0, -rng.uniform(1.0, 100.0), math.nan, rng.uniform(2e4, 1e9)])
    transfer_id = rng.choice([1, rng.randrange(2, 256)])
    bad = _with_kv(_good(60.0), bad_kv)
    host.handshake()
    host.keepalive = heartbeat
    for attempt, hello_first in enumerate([False, rng.random() < 0.5, True]):
        if hello_first:
            host.handshake()  # a restarted host: its transfer ids from 1 again
        start = len(host.received)
        answers = _upload(host, bad, transfer_id)
        assert _refused(answers), f"{target.name}: attempt {attempt} (KV {bad_kv}) answered {answers}"
        assert _calibration_logs(host, start, "refused"), f"{target.name}: attempt {attempt}: no Log"
    good_kv = rng.uniform(40.0, 80.0)
    start = len(host.received)
    answers = _upload(host, _good(good_kv), transfer_id)
    assert all(isinstance(a, Ack) for a in answers), answers
    assert _calibration_logs(host, start, "for unit 0 stored"), f"{target.name}: the good set not stored"


def test_a_hello_forgets_an_unfinished_transfer(target, host):
    """A host restarted in the middle of an upload numbers its next transfer 1 again, with another set."""
    host.handshake()
    host.keepalive = heartbeat
    old = fragment(0, 1, _good(55.0))
    assert all(isinstance(host.request(part), Ack) for part in old[:2])
    host.handshake()
    start = len(host.received)
    answers = _upload(host, _good(70.0), 1)
    assert all(isinstance(a, Ack) for a in answers), f"{target.name}: {answers}"
    assert _calibration_logs(host, start, "for unit 0 stored"), f"{target.name}: the new set not stored"
