"""Beside the tested download that completes: a calibration download whose caller timed out.

A board slow to send its fragments (a busy main loop, a stalled link) let ``download_calibration`` raise
:class:`LinkTimeout`, yet the session kept the download tracked: each timed-out download stayed held for
the rest of the session, and its fragments, arriving late, were acknowledged into a download nobody read —
the board took the transfer for delivered while the caller had been told it failed. Now the timed-out
download is dropped: its late fragments are refused ``BAD_STATE``, and nothing stays held.

The board is played on the far side of a real pseudo-terminal with the protocol's own codec; the host is
the real :class:`BoardClient` on the pty's path (pyserial).
"""

from __future__ import annotations

import os
import select
import threading
import tty
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.link.board import BoardClient
from protocol.calibration import default_unit_calibration, fragment
from protocol.errors import LinkTimeout
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    SCHEMA_HASH,
    Ack,
    BoardState,
    CalibrationRequest,
    Hello,
    HelloReply,
    Nack,
    NackReason,
)


class SlowBoard:
    """A board on a pty's master side: answers the Hello and acknowledges a CalibrationRequest, but keeps
    the requested fragments until :meth:`release` (a board too slow for the caller's timeout)."""

    def __init__(self, master: int) -> None:
        self.master = master
        self.framer = Framer()
        self.deframer = Deframer()
        self.requests: list[CalibrationRequest] = []
        self.answers: list[Ack | Nack] = []
        self.lock = threading.Lock()
        self.stop = threading.Event()

    def serve(self) -> None:
        while not self.stop.is_set():
            if not select.select([self.master], [], [], 0.02)[0]:
                continue
            try:
                data = os.read(self.master, 4096)
            except OSError:
                continue
            for event in self.deframer.feed(data):
                if isinstance(event, Frame):
                    self.take(event)

    def take(self, frame: Frame) -> None:
        msg = frame.message
        if isinstance(msg, Hello):
            reply = HelloReply(
                schema_hash=SCHEMA_HASH, state=BoardState.DISARMED, n_units=2, frame_rate_hz=50, boot_id=7
            )
            self.say(reply)
        elif isinstance(msg, CalibrationRequest):
            with self.lock:
                fresh = all(r.transfer_id != msg.transfer_id for r in self.requests)
                if fresh:
                    self.requests.append(msg)
            self.say(Ack(msg_id=frame.msg_id, seq=frame.seq))
        elif isinstance(msg, (Ack, Nack)):
            with self.lock:
                self.answers.append(msg)

    def say(self, message: object) -> None:
        os.write(self.master, self.framer.encode(message)[1])

    def release(self, request: CalibrationRequest) -> int:
        """Send the set ``request`` asked for, late; returns how many fragments."""
        parts = fragment(request.unit, request.transfer_id, default_unit_calibration().to_bytes())
        for part in parts:
            self.say(part)
        return len(parts)


@contextmanager
def slow_board(tmp: Path) -> Iterator[tuple[Path, SlowBoard]]:
    master, slave = os.openpty()
    tty.setraw(slave)
    link = tmp / "board"
    link.symlink_to(os.ttyname(slave))
    board = SlowBoard(master)
    thread = threading.Thread(target=board.serve, name="slow-board", daemon=True)
    thread.start()
    try:
        yield link, board
    finally:
        board.stop.set()
        thread.join(timeout=5.0)
        os.close(master)
        os.close(slave)


def answers_to(board: SlowBoard, transfer_id: int, n: int, client: BoardClient) -> list[Ack | Nack]:
    """The host's answers to ``n`` fragments of ``transfer_id``, waited for (the client driven meanwhile)."""
    from protocol.messages import CalibrationData

    def got() -> list[Ack | Nack]:
        with board.lock:
            return [a for a in board.answers if a.msg_id == CalibrationData.MSG_ID]

    assert client.wait_for(lambda: len(got()) >= n, timeout=5.0), got()
    return got()


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(downloads=st.integers(1, 3), timeout=st.sampled_from([0.05, 0.15]))
def test_a_timed_out_downloads_late_fragments_are_refused_and_nothing_stays_held(
    tmp_path_factory: pytest.TempPathFactory, downloads: int, timeout: float
) -> None:
    with slow_board(tmp_path_factory.mktemp("pty")) as (link, board):
        client = BoardClient(str(link))
        try:
            client.connect(timeout=5.0)
            for _ in range(downloads):
                with pytest.raises(LinkTimeout, match="unit 1"):
                    client.download_calibration(1, timeout=timeout)
                assert client.session.downloads_running == 0  # not held for the rest of the session
            with board.lock:
                requests = list(board.requests)
            assert len(requests) == downloads
            sent = 0
            for request in requests:
                sent += board.release(request)
            answers = answers_to(board, requests[0].transfer_id, sent, client)
            assert all(isinstance(a, Nack) and a.reason is NackReason.BAD_STATE for a in answers), answers
            assert client.session.downloads_running == 0
        finally:
            client.close()


class GivingUpBoard(SlowBoard):
    """Sends the first ``sent`` fragments of a requested set at once and never the rest: a board that gave
    the transfer up (its resends of a fragment the host's answers never reached all lost on a stalled
    link), while the link itself stays up."""

    sent = 1

    def take(self, frame: Frame) -> None:
        super().take(frame)
        if isinstance(frame.message, CalibrationRequest):
            request: CalibrationRequest = frame.message
            parts = fragment(request.unit, request.transfer_id, default_unit_calibration().to_bytes())
            for part in parts[: self.sent]:
                self.say(part)


@pytest.mark.parametrize("sent", [0, 1, 2])
def test_a_download_the_board_gave_up_fails_without_a_timeout_of_the_callers(
    tmp_path: Path, sent: int
) -> None:
    """``download_calibration(unit)`` without a timeout (as the calibration cycle calls it) on a board
    that stopped sending fragments: a LinkTimeout after ``download_idle_s``, not a wait for ever."""
    import time

    from hil.link.board import ClientConfig

    master, slave = os.openpty()
    tty.setraw(slave)
    link = tmp_path / "board"
    link.symlink_to(os.ttyname(slave))
    board = GivingUpBoard(master)
    board.sent = sent
    thread = threading.Thread(target=board.serve, name="giving-up-board", daemon=True)
    thread.start()
    client = BoardClient(str(link), config=ClientConfig(download_idle_s=0.5, silence_after_s=30.0))
    outcome: list[BaseException | None] = []
    try:
        client.connect(timeout=5.0)
        caller = threading.Thread(
            target=lambda: outcome.append(_raised(lambda: client.download_calibration(1))), daemon=True
        )
        started = time.monotonic()
        caller.start()
        caller.join(timeout=8.0)
        assert not caller.is_alive(), "download_calibration waited for ever on a board that gave it up"
        assert time.monotonic() - started < 5.0
        (error,) = outcome
        assert isinstance(error, LinkTimeout) and "no fragment from the board" in str(error), error
        assert "unit 1" in str(error) and client.session.downloads_running == 0
    finally:
        client.close()
        board.stop.set()
        thread.join(timeout=5.0)
        os.close(master)
        os.close(slave)


def _raised(call: object) -> BaseException | None:
    try:
        call()  # type: ignore[operator]
    except BaseException as exc:  # noqa: BLE001 - handed to the test's thread
        return exc
    return None
