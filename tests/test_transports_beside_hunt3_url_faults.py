"""pyserial URLs beside the path: a ``socket://`` (or ``rfc2217://``, ``spy://``) URL whose port is out of
0..65535 or not a number, or with an option the handler does not know, is refused by pyserial inside its
``open()`` and wrapped in a ``SerialException`` — which the transport took for a port not there yet: ``hil
run --port socket://localhost:99999`` tried again for its whole outage bound (15 s) and then said only
``'debug|info|warning|error'`` (a stray ``{...}`` in pyserial's own error message). Such a URL is now a
:class:`TransportRefused` at once, saying what is wrong with it; a far side that refuses the connection
(nothing listening yet) is still tried again."""

from __future__ import annotations

import os
import pty
import socket
import subprocess
import sys
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.link.transports import create_transport
from protocol.errors import TransportError, TransportRefused


def _refusal(url: str) -> TransportRefused:
    transport = create_transport(url)
    with pytest.raises(TransportRefused) as caught:
        transport.open()
    transport.close()
    return caught.value


@given(port=st.one_of(st.integers(65536, 10**30), st.integers(-(10**30), -1)))
@settings(max_examples=40, deadline=None)
def test_a_socket_port_outside_its_range_is_refused_at_once_naming_it(port):
    said = str(_refusal(f"socket://localhost:{port}"))
    assert "bad URL or options" in said and ("range" in said or "cast" in said)
    assert "debug|info|warning|error" not in said


@pytest.mark.parametrize(
    ("url", "reason"),
    [
        ("socket://localhost:abc", "abc"),
        ("socket://localhost:1?foo=1", "unknown option: 'foo'"),
        ("socket://localhost:1?logging=bogus", "'bogus'"),
        ("socket://[::1:1234", "IPv6"),
        ("rfc2217://localhost:99999", "range"),
        ("spy://loop://?bogus=1", "unknown option: 'bogus'"),
        ("loop://?foo=1", "unknown option: 'foo'"),  # was refused, quoting pyserial's stray '{...}'
    ],
)
def test_a_pyserial_url_its_handler_refuses_is_refused_saying_why(url, reason):
    said = str(_refusal(url))
    assert url in said and reason in said
    assert "debug|info|warning|error" not in said


def test_nothing_listening_yet_is_still_a_port_tried_again():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    transport = create_transport(f"socket://127.0.0.1:{port}")
    with pytest.raises(TransportError) as caught:
        transport.open()
    assert not isinstance(caught.value, TransportRefused)


def test_hil_run_on_a_socket_url_with_a_bad_port_ends_at_once_with_one_line(tmp_path):
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--port", "socket://localhost:99999", "--no-plots",
         "--recover-within", "60", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    took = time.monotonic() - started
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "tried for" not in done.stderr and "socket://localhost:99999" in done.stderr
    assert "range" in done.stderr
    assert took < 30.0  # at once, not after the 60 s outage bound (a process start is ~1-2 s, more loaded)


def test_a_path_that_can_never_name_a_port_is_refused_at_once(tmp_path):
    """A name longer than the system takes (ENAMETOOLONG) or a loop of symbolic links (ELOOP) was tried
    again for the run's whole outage bound, like a port not there yet."""
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    for url in (str(loop), "/dev/" + "a" * 5000):
        said = str(_refusal(url))
        assert "not a serial port" in said


def test_a_spy_whose_file_cannot_be_made_is_refused_at_once_naming_it(tmp_path):
    """``spy://PORT?file=`` in a folder that is not there: pyserial's spy opens the file as the URL is read,
    and its FileNotFoundError was taken for a port not there yet and tried again for 15 s."""
    controller, device = pty.openpty()
    try:
        missing = tmp_path / "not-there" / "spy.txt"
        said = str(_refusal(f"spy://{os.ttyname(device)}?file={missing}"))
        assert "bad URL or options" in said and "No such file" in said
    finally:
        os.close(controller)
        os.close(device)
