"""Transports through their real interfaces: a real pty with pyserial, pyserial URL handlers."""

import contextlib
import os
import threading
import time

import pytest

from hil.link.transports import UrlOptions, create_transport, open_transport
from protocol.errors import LinkError, TransportError


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    name = os.ttyname(slave)
    yield master, name
    for fd in (master, slave):
        with contextlib.suppress(OSError):  # the test may have closed it already
            os.close(fd)


def test_serial_over_real_pty_both_ways(pty_pair):
    master, name = pty_pair
    with open_transport(name) as t:
        os.write(master, b"\x01\x02\x00")
        got = b""
        for _ in range(20):
            got += t.read(0.1)
            if len(got) >= 3:
                break
        assert got == b"\x01\x02\x00"
        t.write(b"hello")
        assert os.read(master, 16) == b"hello"
        assert (t.bytes_in, t.bytes_out) == (3, 5)


def test_read_times_out_empty(pty_pair):
    _, name = pty_pair
    with open_transport(name) as t:
        assert t.read(0.01) == b""


def test_vanished_far_side_is_a_link_error(pty_pair):
    master, name = pty_pair
    t = open_transport(name)
    os.close(master)
    with pytest.raises(LinkError):
        for _ in range(5):
            t.read(0.05)
    t.close()
    t.close()  # idempotent
    with pytest.raises(LinkError):
        t.read(0.01)


@pytest.mark.parametrize("closed_after_s", [0.0, 0.02, 0.1])
def test_a_port_closed_by_another_thread_under_a_read_is_a_link_error(pty_pair, closed_after_s):
    """A reconnect closes the port while the reader thread waits in a read: pyserial then fails on its
    released descriptor (a TypeError, not its own exception), which the reader thread took for a bug of its
    own — the client's "reader thread failed", a run ended as an error. Whatever the backend raises after
    the close is a LinkError, as a vanished port is; the port's reads and writes keep failing so."""
    _, name = pty_pair
    t = open_transport(name)
    raised: list[BaseException] = []

    def reader() -> None:
        try:
            while True:
                t.read(0.2)
        except BaseException as exc:  # noqa: BLE001 - the test looks at what the read raised
            raised.append(exc)

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    time.sleep(closed_after_s)
    t.close()
    thread.join(5.0)
    assert not thread.is_alive()
    [exc] = raised
    assert isinstance(exc, LinkError), repr(exc)
    with pytest.raises(LinkError):
        t.write(b"x")


def _link_to(link, device) -> None:
    """``link`` made anew to ``device``, as firmware-sim makes its ``--link`` (a new symbolic link)."""
    tmp = link.with_name(link.name + ".new")
    tmp.symlink_to(device)
    tmp.replace(link)


def test_a_link_whose_pty_number_another_program_now_has_is_not_our_board_back(tmp_path):
    """A firmware-sim killed leaves its ``--link`` to a pty that went away; the kernel gives that pty's
    number to the next program that asks (another board's firmware-sim, a terminal). The link unchanged
    then leads to that program's pty: the client, watching the path to reconnect, opened it, sent it a
    Hello (another board: disarmed by it) and held its port — a pty campaign's host refused "port busy,
    held by" the other test's client. Until the link is made anew (our board started again), the path is
    not there for the client, and an open is refused saying why."""
    link = tmp_path / "board"
    master, slave = os.openpty()
    device = os.ttyname(slave)
    os.close(slave)
    _link_to(link, device)
    t = create_transport(str(link))
    t.open()
    assert t.present() is True
    os.close(master)  # the board's process dies: its side of the pty closes
    with pytest.raises(LinkError):
        for _ in range(5):
            t.read(0.05)
    t.close()
    held = []
    try:
        while not os.path.exists(device) and len(held) < 64:  # the number given out again (lowest first)
            held.append(os.openpty())
        assert os.path.exists(device), "the pty's number was not given out again"
        assert t.present() is False
        with pytest.raises(TransportError, match="whose number another program now has"):
            t.open()
        if any(os.ttyname(slave) == device for _, slave in held):  # the number is ours, not another test's
            _link_to(link, device)  # our board started again (on the same number, as it may be): a new link
            assert t.present() is True
            t.open()
            t.close()
    finally:
        for pair in held:
            for fd in pair:
                os.close(fd)


def test_a_port_closed_under_a_read_by_our_own_close_is_still_ours_to_open_again(tmp_path, pty_pair):
    """Our own close under a read (a reconnect's) is no sign that the far side went away: the link is
    opened again as it is."""
    master, device = pty_pair
    link = tmp_path / "board"
    _link_to(link, device)
    t = create_transport(str(link))
    t.open()
    t.close()
    assert t.present() is True
    t.open()
    os.write(master, b"x")
    assert t.read(0.5) == b"x"
    t.close()


def test_loop_url_and_unknown_things():
    with open_transport("loop://") as t:
        t.write(b"abc")
        assert t.read(0.1) == b"abc"
    with pytest.raises(TransportError, match="unknown transport scheme"):
        create_transport("nope://x")
    with pytest.raises(TransportError, match="/dev/does-not-exist"):
        open_transport("/dev/does-not-exist")
    with pytest.raises(TransportError):
        open_transport("loop://?bogus=1")


def test_url_options_reject_unknown_and_bad_values():
    opts = UrlOptions("can://virtual/ch0?fd=1&bitrate=500000&x=2")
    assert opts.get_bool("fd", False) is True
    assert opts.get_int("bitrate", 0) == 500000
    with pytest.raises(TransportError, match="unknown option"):
        opts.finish()
    with pytest.raises(TransportError, match="not a number"):
        UrlOptions("x://y?t=abc").get_float("t", 1.0)


@pytest.mark.parametrize("url", ["emu://?units=0", "spawn://firmware-sim?units=0", "emu://?noise=5:1:2"])
def test_a_board_its_options_cannot_describe_fails_the_run_at_once_not_after_retries(tmp_path, url):
    """A value the board refuses is no port that may come back: the run says so at once (it was tried
    again for the whole outage bound, 15 s, a spawned firmware-sim started over and over)."""
    import json
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--port", url, "--phone-wait", "3", "--duration", "1",
         "--no-plots", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "tried for" not in done.stderr and url in done.stderr
    events = [json.loads(line) for line in next(tmp_path.glob("*/events.jsonl")).read_text().splitlines()]
    assert not [e for e in events if e["kind"] == "connect_retry"]


@pytest.mark.parametrize("url", ["emu://?units=3&units=5", "emu://?frame-rate=100&frame_rate=200"])
def test_an_emulator_option_given_twice_is_refused_naming_it(url):
    """argparse keeps an option's last value: a URL that says two things is refused, not half-read."""
    with pytest.raises(TransportError, match="given twice"):
        create_transport(url)


@pytest.mark.parametrize(
    ("args", "said"),
    [(["--phone-jump", "1:1e308", "--world", "cubesat-1u"], "within"),
     (["--phone-jump", "1:0", "--world", "cubesat-1u"], "non-zero"),
     (["--noise", "1:1e9:0.5"], "duration"), (["--noise", "1:1:2"], "probability"),
     (["--phone-gap", "1:1"], "needs --world"), (["--phone-spoof", "1:huge"], "needs --world")],
)  # fmt: skip
def test_firmware_sim_s_fault_options_out_of_range_are_usage_errors_naming_them(args, said):
    """A phone clock's jump of 1e308 s crashed the world's thread (its datagram's stamp overflowed); a
    noise burst of 1e9 s was taken; phone faults without a world were accepted and ignored."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--duration", "0.2", *args],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert said in done.stderr and args[0] in done.stderr


def test_repeatable_fault_options_may_repeat():
    assert create_transport("emu://?stall=1:1&stall=3:1") is not None
