"""Transports through their real interfaces: a real pty with pyserial, pyserial URL handlers."""

import contextlib
import os

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
