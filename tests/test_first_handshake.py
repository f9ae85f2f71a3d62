"""The first handshake, tried again while the board's port comes back (:func:`hil.link.board.connect_within`,
shared by ``hil run`` and ``hil calibrate``).

In lockstep, against the in-process board's own ``unplug`` fault at drawn moments: before the port is
opened and under the handshake (the board stalled, so its Hellos go unanswered, then its cable pulled).
Through the real interface: real ``firmware-sim`` processes on real ptys, stopped so the handshake stays
open, killed (SIGKILL) at a drawn moment after ``hil calibrate`` opened their port and started again on
the same ``--link``, or not. Each drawn moment is seeded; bounds are generous (a busy CPU beside the
tests slows a process's start by seconds), the wall time of each test a few seconds.

Defect these found: ``hil calibrate`` ended at once (``no session with the board ...``, status 2) when its
board was restarted under its first handshake, where ``hil run`` waits for it within its outage bound.
"""

from __future__ import annotations

import os
import random
import signal
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from operator_support import Operated
from sim_support import Sim, sims

from firmware_sim.servers.transports import EmulatorTransport
from hil.link.board import BoardClient, ClientConfig, ConnectRetry, connect_within
from hil.timing.clock import LockstepClock
from protocol.errors import HandshakeError, LinkTimeout, TransportError, TransportRefused

SEED = 20261206
SIM = ["--units", "2", "--esc-supply-switch", "--link-timeout", "1"]
ESC = ["--unit", "0", "--confirm-unloaded", "--supply-off-ms", "300", "--high-ms", "500", "--low-ms", "300"]
WALL_S = 60.0  # every tool run ends within this, however busy the machine


# ====================================================================== lockstep: the shared function
def lockstep(
    query: str = "units=2", **config: object
) -> tuple[BoardClient, EmulatorTransport, LockstepClock]:
    clock = LockstepClock()
    transport = EmulatorTransport(f"emu://?{query}", clock)
    return BoardClient(transport, config=ClientConfig(**config)), transport, clock  # type: ignore[arg-type]


def check_retries(retries: list[ConnectRetry], client: BoardClient, within_s: float) -> None:
    """Numbered from 0, each with the client's back-off, each before the bound, in time order."""
    assert [r.attempt for r in retries] == list(range(len(retries)))
    assert all(r.delay_s == client.config.reconnect_delay(r.attempt) for r in retries)
    assert all(0.0 <= r.waited_s < within_s for r in retries)
    assert all(b.t >= a.t + a.delay_s for a, b in zip(retries, retries[1:], strict=False))


@settings(max_examples=40, deadline=None)
@given(out_s=st.floats(0.01, 4.0), within_s=st.floats(0.0, 8.0))
def test_a_port_away_at_the_first_connect_is_waited_for_within_the_bound(out_s, within_s):
    """The board's cable out when the host connects, for ``out_s``: connected once it is back if that is
    within ``within_s`` (plus the back-off's last wait), else a TransportError saying how long it tried;
    each retry reported, none after the bound."""
    client, transport, clock = lockstep()
    transport.board.faults.unplug(out_s, at=0.0)
    retries: list[ConnectRetry] = []
    try:
        info = connect_within(client, within_s, retries.append)
    except TransportError as exc:
        assert not isinstance(exc, TransportRefused)
        assert "the port vanished" in str(exc) and "tried for" in str(exc)
        assert clock.now() >= within_s and not client.connected and not transport.is_open
        assert clock.now() < out_s + 1e-6  # given up while the port was still away
    else:
        assert info.n_units == 2 and client.connected
        assert clock.now() >= out_s and retries  # it was away: tried again until it came back
        assert retries[-1].t < out_s <= retries[-1].t + retries[-1].delay_s + 1e-6
    check_retries(retries, client, within_s)
    assert all("the port vanished" in str(r.error) for r in retries)
    client.close()


@settings(max_examples=40, deadline=None)
@given(pulled_at=st.floats(0.01, 2.0), out_s=st.floats(0.01, 3.0))
def test_a_port_that_vanishes_under_the_first_handshake_is_waited_for(pulled_at, out_s):
    """The board silent (stalled) after the host opened its port, then its cable pulled at a drawn moment
    of the handshake's 5 s of Hellos, back ``out_s`` later: a retry, then a session."""
    client, transport, clock = lockstep()
    transport.board.faults.stall(pulled_at + out_s + 1.0, at=0.0)  # no answer before the cable is pulled
    transport.board.faults.unplug(out_s, at=pulled_at)
    retries: list[ConnectRetry] = []
    info = connect_within(client, 30.0, retries.append)
    assert info.n_units == 2 and client.connected
    assert retries and abs(retries[0].t - pulled_at) < 0.2, (retries[0], pulled_at)
    assert "the port vanished" in str(retries[0].error)
    check_retries(retries, client, 30.0)
    client.close()


def test_what_no_second_try_can_mend_fails_at_once():
    """No answer (LinkTimeout), another protocol (HandshakeError), a URL that describes no board
    (TransportRefused): raised as they are, never retried, whatever the bound."""
    retried: list[ConnectRetry] = []
    silent, transport, clock = lockstep()
    transport.board.faults.stall(60.0, at=0.0)
    with pytest.raises(LinkTimeout, match="did not answer the handshake"):
        connect_within(silent, 30.0, retried.append)
    assert clock.now() < 6.0  # its handshake's tries (5 s), not the bound
    other, _, _ = lockstep(schema_hash=12345)
    with pytest.raises(HandshakeError):
        connect_within(other, 30.0, retried.append)
    nothing, _, _ = lockstep("units=0")
    with pytest.raises(TransportRefused):
        connect_within(nothing, 30.0, retried.append)
    assert retried == []


# ====================================================================== real processes: hil calibrate
class Tool(Operated):
    """``python -m hil ARGV`` with a pty for stdin, its stdout and stderr read line by line as they come."""

    def ended(self, timeout: float = WALL_S) -> tuple[int, str, str]:
        """(exit status, stdout, stderr) once it has ended (killed after ``timeout`` s)."""
        code, err = self.finish(timeout)
        return code, self.stdout, err


def stopped_board(tmp: Path, started: list[Sim]) -> tuple[Path, Sim]:
    """A firmware-sim on ``tmp/board``, stopped (SIGSTOP): its port is there and answers nothing."""
    link = tmp / "board"
    sim = Sim(tmp, link, *SIM)
    started.append(sim)
    sim.proc.send_signal(signal.SIGSTOP)
    return link, sim


def retry_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if "trying again in" in line]


def check_no_traceback(code: int, err: str) -> None:
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == (code == 2), err


@pytest.mark.parametrize("index", range(3))
def test_a_board_restarted_under_calibrate_s_first_handshake_is_connected_to(tmp_path, index):
    """The board killed at a drawn moment of the handshake's window (after the tool opened its port, the
    board stopped so it has not answered) and started again on the same path a drawn time later: the
    retries are said on stderr, the session is made and the ESC is taught. Before the fix: status 2,
    ``no session with the board at ...`` at once."""
    rng = random.Random(SEED + index)
    with sims(tmp_path) as started:
        link, first = stopped_board(tmp_path, started)
        tool = Tool(["calibrate", "esc", "--port", str(link), *ESC, "--connect-within", "30"])
        tool.wait_for_open(first.path)
        time.sleep(rng.uniform(0.0, 2.0))  # within its 5 s of unanswered Hellos
        first.kill()
        time.sleep(rng.uniform(0.1, 1.0))
        started.append(Sim(tmp_path, link, *SIM))
        code, out, err = tool.ended()
    check_no_traceback(code, err)
    assert code == 0 and "unit 0: ESC taught 1000-2000 us" in out, (code, out, err)
    said = retry_lines(err)
    assert said and all(
        line.startswith(f"hil calibrate: no session with the board at {link} yet (") for line in said
    )
    assert "of 30 s)" in said[-1]


@pytest.mark.parametrize("index", range(2))
def test_a_board_not_back_within_the_bound_ends_the_tool_having_done_nothing(tmp_path, index):
    """The board killed under the handshake and never started again: after ``--connect-within`` (its
    default, 5 s) the tool ends with status 2, one error naming the port and how long it tried, ``nothing
    was done``; no step was taken (nothing printed on stdout, no board put back to rest)."""
    rng = random.Random(SEED * 10 + index)
    with sims(tmp_path) as started:
        link, first = stopped_board(tmp_path, started)
        tool = Tool(["calibrate", "esc", "--port", str(link), *ESC])  # the default bound: 5 s
        tool.wait_for_open(first.path)
        time.sleep(rng.uniform(0.0, 1.0))  # the bound counts from the first try: killed well within it
        first.kill()
        killed = time.monotonic()
        code, out, err = tool.ended()
    check_no_traceback(code, err)
    assert code == 2 and out == "", (code, out, err)
    last = err.splitlines()[-1]
    assert last.startswith(f"hil calibrate: error: no session with the board at {link} (")
    assert "(tried for" in last and last.endswith("; nothing was done"), last
    said = retry_lines(err)
    assert said and "of 5 s)" in said[-1] and "left" not in err, err
    assert time.monotonic() - killed < 25.0  # the bound (5 s) and the back-off's last wait, not more


@pytest.mark.parametrize("held", [False, True], ids=["silent", "held-by-another-host"])
def test_a_port_that_answers_nothing_or_is_held_fails_at_once(tmp_path, held):
    """A port that is there but answers nothing (a board stopped) ends the tool after its handshake's
    tries (5 s), not after ``--connect-within``; one another host holds ends it at once. Neither is
    retried."""
    with sims(tmp_path) as started:
        if held:
            link = tmp_path / "board"
            started.append(Sim(tmp_path, link, *SIM))
            holder = BoardClient(str(link))
            holder.connect()
        else:
            link, _ = stopped_board(tmp_path, started)
        try:
            t0 = time.monotonic()
            tool = Tool(["calibrate", "esc", "--port", str(link), *ESC, "--connect-within", "40"])
            code, out, err = tool.ended()
            took = time.monotonic() - t0
        finally:
            if held:
                holder.close()
    check_no_traceback(code, err)
    assert code == 2 and out == "" and retry_lines(err) == [], (code, out, err)
    assert f"no session with the board at {link}" in err and "nothing was done" in err
    assert ("port busy" if held else "did not answer the handshake") in err, err
    assert took < 35.0  # well within the bound: not retried (the handshake's tries take 5 s)


@pytest.mark.parametrize("index", range(2))
def test_an_interrupt_during_the_retries_ends_cleanly(tmp_path, index):
    """Ctrl-C or SIGTERM (drawn) while the tool waits for its board to come back: it ends at once with
    the signal's status (130, 143), saying no session was made and nothing done; no traceback."""
    rng = random.Random(SEED * 20 + index)
    signum = rng.choice([signal.SIGINT, signal.SIGTERM])
    with sims(tmp_path) as started:
        link, first = stopped_board(tmp_path, started)
        tool = Tool(["calibrate", "esc", "--port", str(link), *ESC, "--connect-within", "60"])
        tool.wait_for_open(first.path)
        first.kill()
        tool.wait_for_error("trying again in")
        time.sleep(rng.uniform(0.0, 1.0))
        tool.proc.send_signal(signum)
        sent = time.monotonic()
        code, out, err = tool.ended()
    assert "Traceback" not in err, err
    assert code == 128 + signum and out == "", (code, out, err)
    lines = err.splitlines()
    assert lines[-2] == f"hil calibrate: no session with the board at {link}; nothing was done", err
    assert lines[-1] == f"hil calibrate: interrupted ({signal.Signals(signum).name})", err
    assert time.monotonic() - sent < 15.0


def _not_ports(tmp_path: Path) -> list[str]:
    """Port URLs that are there but are no serial port, or that name no board however long they are
    tried: a folder, a regular file, a FIFO, a device that is no terminal, a URL's bad option, a python-can
    interface that does not exist."""
    (tmp_path / "a-file").write_text("not a port")
    os.mkfifo(tmp_path / "a-fifo")
    fifo = str(tmp_path / "a-fifo")
    return [
        str(tmp_path),
        str(tmp_path / "a-file"),
        fifo,
        "/dev/null",
        "loop://?logging=bogus",
        "can://bogus/x",
    ]


def test_a_port_that_is_no_serial_port_fails_at_once_never_retried(tmp_path):
    """Each was retried for the whole bound (15 s by default; for ever with ``--recover-within 1e308``):
    EISDIR and ENOTTY, a URL's bad option and a CAN interface python-can does not have are
    :class:`TransportRefused` on the first try."""
    for url in _not_ports(tmp_path):
        client = BoardClient(url)
        t0 = time.monotonic()
        with pytest.raises(TransportRefused) as err:
            connect_within(client, 600.0)  # a retry would wait: the first back-off is 0.5 s and more
        assert url in str(err.value) and "tried for" not in str(err.value)
        assert time.monotonic() - t0 < 5.0  # the first try's; loaded machines included
        client.close()


def test_a_port_that_is_not_there_yet_is_still_waited_for(tmp_path):
    """The path's other side: a device not there (a board not plugged in yet) is tried again, within the
    bound, as before."""
    client = BoardClient(str(tmp_path / "ttyACM9"))
    with pytest.raises(TransportError) as err:
        connect_within(client, 2.0)
    assert not isinstance(err.value, TransportRefused) and "tried for" in str(err.value)
    client.close()


@pytest.mark.parametrize("option", ["--recover-within", "--phone-wait", "--duration"])
def test_a_wait_longer_than_a_day_is_refused_by_hil_run(option, capsys):
    from hil.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["run", option, "1e308"])
    assert exit_.value.code == 2 and option in capsys.readouterr().err


def test_a_connect_within_longer_than_a_day_is_refused_by_hil_calibrate(tmp_path, capsys):
    from hil.cli import main

    code = main(["calibrate", "esc", "--port", str(tmp_path / "none"), *ESC, "--connect-within", "1e308"])
    assert code == 2 and "--connect-within" in capsys.readouterr().err
