"""The host's view of a board whose client reads on its own thread (real time, ``BoardClient.start``): the
telemetry the view shows is the message whose time it is aged by, never an older message beside a newer
frame's time (:meth:`hil.link.board.BoardClient.latest_telemetry`, :meth:`hil.runtime.watch.BoardWatch.view`).

What broke: ``view`` read ``client.telemetry`` and then ``client.telemetry_time``; the reader thread could
take a frame between the two reads (about one view in 10 000 at 500 Hz telemetry), and the view then paired
the older message with the newer frame's time. After a stall, that older message is the one from before
it — ARMED, its rotors at speed — shown live with the first new frame's time while that frame said
FAILSAFE; ``hold_armed`` and ``hold_disarmed`` judged the view's message by the client's newer time too.

The real built-in emulator (``emu://``) on the wall clock, the client's own reader thread; the interpreter's
switch interval shortened for the test so that the threads interleave often.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hil.link.board import BoardClient
from hil.link.board.events import Event, TelemetryEvent
from hil.runtime.faults import BoardLink, FaultJournal
from hil.runtime.runlog import EventLog
from hil.runtime.watch import BoardWatch
from hil.timing.clock import WallClock
from protocol.messages import Telemetry

VIEWING_S = 3.0  # wall seconds of views: ~50 torn ones before the fix, at the rate below
TELEMETRY_HZ = 500


@pytest.fixture
def fine_switching() -> Iterator[None]:
    """Threads switched every microsecond (the default is 5 ms) for the test's duration."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def test_the_view_never_pairs_an_older_telemetry_with_a_newer_frames_time(tmp_path: Path, fine_switching):
    """Views taken as fast as the host can while the reader thread takes 500 frames a second: each live
    view's message was made at the time its age and ``made_s`` say (the time the client took it at)."""
    made: dict[int, tuple[Telemetry, float]] = {}  # id → (the message, kept alive; when it was made)

    def on_event(event: Event) -> None:
        """On the reader thread, under the client's lock, after the read that brought ``event``: the
        session's pair is this message's if it was the read's last (a read of several frames dates the
        others by the board's clock: no reference for those)."""
        session = client.session
        if isinstance(event, TelemetryEvent) and session.telemetry is event.telemetry:
            assert session.telemetry_time is not None
            made[id(event.telemetry)] = (event.telemetry, session.telemetry_time)

    clock = WallClock()
    url = f"emu://?units=4&telemetry_rate={TELEMETRY_HZ}"
    client = BoardClient(url, clock=clock, on_event=on_event)
    events = EventLog(tmp_path / "events.jsonl")
    try:
        client.connect()
        client.start()
        watch = BoardWatch(client, events, FaultJournal(), 0.25)
        torn: list[tuple[float, float]] = []  # (the message's time, the time the view aged it from)
        misdated: list[tuple[float, float | None]] = []  # (the message's time, the view's made_s)
        live = 0
        end = time.monotonic() + VIEWING_S
        while time.monotonic() < end:
            t = clock.now()
            view = watch.view(t)
            if view.link is not BoardLink.LIVE or view.telemetry is None:
                continue
            live += 1
            own = made.get(id(view.telemetry))
            if own is None or own[0] is not view.telemetry:
                continue  # no reference for it (see on_event)
            assert view.age_s is not None
            aged_from = t - view.age_s
            if abs(aged_from - own[1]) > 1e-6:
                torn.append((own[1], aged_from))
            elif view.made_s != pytest.approx(own[1], abs=1e-9):
                misdated.append((own[1], view.made_s))
        assert live > 1_000, live
        assert not torn, f"{len(torn)} of {live} live views paired a message with another's time: {torn[:3]}"
        assert not misdated, (
            f"{len(misdated)} live views said another time than the message's: {misdated[:3]}"
        )
    finally:
        client.close()
        events.close()
