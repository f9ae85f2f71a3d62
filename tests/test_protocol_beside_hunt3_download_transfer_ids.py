"""Beside the tested single download: a download of the same unit again once the session's transfer ids
(one byte) have wrapped — 256 transfers later, uploads included, as a calibration bench's upload cycles
make. The session's one reassembler still held the set it completed last, and the new download (same
unit, same transfer id, same set) had every fragment taken for a repeat of it: acknowledged, dropped, and
the download never completed (``LinkTimeout``; without a timeout, a hang)."""

from __future__ import annotations

import pytest

from firmware_sim.servers.transports import EmulatorTransport
from hil.link.board import BoardClient, ClientConfig
from hil.timing.clock import LockstepClock
from protocol.calibration import default_unit_calibration

TRANSFER_IDS = 256  # CalibrationRequest.transfer_id / CalibrationData.transfer_id: one byte


@pytest.mark.parametrize("downloaded, uploaded", [(0, 1), (3, 3)])
def test_a_download_after_the_transfer_ids_wrapped_completes(downloaded: int, uploaded: int) -> None:
    clock = LockstepClock()
    client = BoardClient(EmulatorTransport("emu://?units=4&telemetry_rate=50", clock), config=ClientConfig())
    client.connect()
    base = default_unit_calibration()
    assert client.download_calibration(downloaded, timeout=5.0).to_bytes() == base.to_bytes()
    for _ in range(TRANSFER_IDS - 1):  # every transfer id but the download's used once more
        client.upload_calibration(uploaded, base, timeout=5.0)
    again = client.download_calibration(downloaded, timeout=5.0)  # the same unit, transfer id and set
    assert again.to_bytes() == base.to_bytes()
    assert client.download_calibration(downloaded, timeout=5.0).to_bytes() == base.to_bytes()
    client.close()
