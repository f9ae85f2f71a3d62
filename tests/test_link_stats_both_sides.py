"""The same link statistics on both sides of every transport and every board: the board client's count of
what it sent and took against ``firmware-sim``'s (in another process) count of what it took and sent, over
a pty and over a CAN bus (``udp_multicast``, classic CAN and CAN FD), for the Python board and the firmware
on simavr — and the host's coming and going and the board's state changes reported alike."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from bench.can_bus import multicast_url
from bench.child import firmware_sim, started
from tests.test_can_link import exchange

_STOPPED = re.compile(
    r"firmware-sim: stopped; (?P<bytes_in>\d+) bytes in, (?P<bytes_out>\d+) out, "
    r"(?P<frames_in>\d+) frames in, (?P<frames_out>\d+) out; "
    r"host left (?P<gone>\d+) time\(s\), came back (?P<back>\d+); "
    r"(?P<errors>\d+) link error\(s\)"
)


def _where(transport: str, tmp_path: Path) -> list[str]:
    """firmware-sim's options for ``transport``: ``pty``/``can``/``can-fd`` serve the Python board,
    ``firmware-pty`` the firmware on simavr (the harness's own pty bridge), ``firmware-can`` the firmware
    stepped from firmware-sim behind its CAN server."""
    board = ["--avr"] if transport.startswith("firmware") else []
    if transport.endswith("pty"):
        return [*board, "--link", str(tmp_path / "board")]
    return [*board, "--can", multicast_url(fd=transport.endswith("fd"))]


BUS = pytest.mark.udp_multicast
FIRMWARE = pytest.mark.firmware


@pytest.mark.parametrize(
    "transport",
    [
        "pty",
        pytest.param("can", marks=BUS),
        pytest.param("can-fd", marks=BUS),
        pytest.param("firmware-pty", marks=FIRMWARE),
        pytest.param("firmware-can-fd", marks=[BUS, FIRMWARE]),
    ],
)
def test_both_ends_count_the_same_frames_and_the_host_leaving(transport, tmp_path):
    options = ["--units", "2", "--telemetry-rate", "50", *_where(transport, tmp_path)]
    with started(firmware_sim(*options)) as board:
        client = exchange(str(tmp_path / "board") if transport.endswith("pty") else board.first_line, 2)
        time.sleep(1.5)  # the host is silent (closed) for longer than HOST_SILENCE_S: gone
    err = board.said
    assert board.proc.returncode == 0, err
    stopped = _STOPPED.search(err)
    assert stopped is not None, err
    board_side = {k: int(v) for k, v in stopped.groupdict().items()}
    host = client.stats()
    # Every frame the host wrote was taken, whole; the board sent at least what the host took (it talks
    # before the host arrives, and on a bus nobody keeps what no host heard).
    assert board_side["frames_in"] == host.counters.frames_out, (board_side, host.counters)
    assert board_side["bytes_in"] == host.bytes_out, (board_side, host.bytes_out)
    assert 0 < host.frames_in <= board_side["frames_out"], (board_side, host.frames_in)
    assert board_side["errors"] == 0 and host.bad_frames_total == 0
    assert board_side["gone"] == 1 and board_side["back"] == 0, err
    assert "host connected" in err and "host left" in err, err
    # Every state change the serving loop saw, however brief; the harness's own pty bridge is looked at
    # every POLL_S (its handshake's DISARMED may pass unseen there: BOOT -> ARMED).
    assert "-> ARMED" in err and "board ARMED -> DISARMED" in err, err
    if not transport.startswith("firmware"):
        assert "board DISARMED -> ARMED" in err, err
