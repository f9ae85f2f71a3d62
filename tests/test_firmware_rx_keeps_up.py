"""The C firmware (on simavr, stepped in lockstep) takes a host's bytes at the full line rate under load:
calibration uploads streamed whole (every fragment in one write, as ``BoardClient.upload_calibration``
sends them) while the board sends a download the host never acknowledges (retried, the transmit line
busy), with up to six units, pulse frames up to 490 Hz and telemetry up to 100 Hz.

CI met it through the differential fuzz (tests/test_firmware_differential.py): with six units at 490 Hz
the main loop took received bytes at ~3 bytes/ms against the line's 11.5, its 384-byte receive ring
overflowed in the second upload, and two fragments went unanswered. The loop's CPU went to the bitwise
CRC (28 %: the whole set's CRC computed again in every download fragment) and to 16-bit divisions (17 %:
the ring's index wrap, twice per received byte); a download now computes its set's CRC once
(firmware/src/app.c, report.c), the CRC goes a byte at a time (crc16.c), and the ring wraps by a
compare (uart.c).

Invariants, whatever is drawn: every fragment is answered exactly once (Ack or Nack, by its sequence
number), the firmware never says it lost received bytes, and its telemetry counts no bad frame.
"""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from firmware_lockstep_support import Host, loaded_configs
from hypothesis import HealthCheck, given, settings
from test_firmware_differential import hostile_sets

from protocol.calibration import default_unit_calibration, fragment
from protocol.messages import SCHEMA_HASH, CalibrationData, CalibrationRequest, Hello

ANSWER_S = 0.4
"""Board time a streamed upload is given for its answers (a heartbeat every 50 ms meanwhile): the line
carries a 414-byte set in 36 ms, and the answers queue behind up to 1 KiB of telemetry and download
fragments (89 ms at 115200 baud)."""


valid_sets = st.just(default_unit_calibration().to_bytes())


@pytest.mark.firmware
@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
@given(data=st.data())
def test_uploads_streamed_during_a_download_are_all_answered_and_no_byte_is_lost(data):
    config = data.draw(loaded_configs, label="config")
    n = config.n_units
    uploads = data.draw(
        st.lists(
            st.tuples(
                st.integers(0, n - 1),
                st.one_of(valid_sets, hostile_sets()),
                st.sampled_from([0.1, ANSWER_S]),
            ),
            min_size=1,
            max_size=3,
        ),
        label="uploads",
    )
    host = Host(config)
    try:
        host.run(0.15)
        host.send(Hello(schema_hash=SCHEMA_HASH, manufacturer="rx", model="keeps-up", serial="R1"), flags=0)
        host.run(0.1)
        host.send(CalibrationRequest(unit=n - 1, transfer_id=7))  # its fragments never acknowledged
        host.run(0.01)
        sent: list[int] = []
        for k, (unit, set_bytes, pause) in enumerate(uploads):
            sent += host.send(*fragment(unit, k, set_bytes))
            host.run(pause, heartbeat_s=0.05)
        host.run(ANSWER_S, heartbeat_s=0.05)
    finally:
        host.close()
    lost = [text for text in host.logs if "lost to a full buffer" in text]
    assert not lost, lost
    answers = {seq: host.answers.get((CalibrationData.MSG_ID, seq), []) for seq in sent}
    not_once = {seq: said for seq, said in answers.items() if len(said) != 1}
    assert not not_once, f"fragments not answered exactly once: {not_once}"
    assert host.rx_bad == 0
