"""pyserial's ``spy://`` (the traffic dump the serial transport documents) beside the path:

1. ``spy://PORT?raw`` dumps the bytes as they are — and pyserial's raw formatter wrote them into a text
   stream (its ``file=``, or stderr): the host's first write was a ``TypeError`` out of ``write()``, ``hil
   run`` ending on a traceback (exit status 1) before its handshake.
2. The dump's ``file=`` is opened anew (emptied) each time pyserial makes the port, and the transport made
   one for every connection: the link's first reconnect emptied the dump of all the traffic before it —
   the traffic up to the loss, which is what a spy is for.

Real ptys, real pyserial; the far side is the pty's master."""

from __future__ import annotations

import os
import subprocess
import sys
import tty

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.link.transports import create_transport


def _pty() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def _read_master(master: int, n: int) -> bytes:
    got = b""
    while len(got) < n:
        got += os.read(master, n - len(got))
    return got


def _read_all(transport, n: int) -> bytes:
    got = b""
    for _ in range(200):
        got += transport.read(0.05)
        if len(got) >= n:
            break
    return got


frames = st.binary(min_size=1, max_size=300).map(lambda b: b.replace(b"\x00", b"\x01") + b"\x00")


@given(sessions=st.lists(st.tuples(frames, frames), min_size=1, max_size=4))
@settings(max_examples=15, deadline=None)
def test_a_raw_spy_dumps_every_byte_both_ways_across_reconnects(tmp_path_factory, sessions):
    master, slave, path = _pty()
    dump = tmp_path_factory.mktemp("spy") / "raw.bin"
    transport = create_transport(f"spy://{path}?raw&file={dump}")
    expected = b""
    try:
        for sent, answered in sessions:  # one connection each: the host reconnects between them
            transport.open()
            transport.write(sent)
            assert _read_master(master, len(sent)) == sent
            os.write(master, answered)
            assert _read_all(transport, len(answered)) == answered
            transport.close()
            expected += sent + answered
    finally:
        transport.close()
        os.close(master)
        os.close(slave)
    assert dump.read_bytes() == expected


def test_a_hexdump_spy_keeps_the_traffic_before_a_reconnect(tmp_path):
    master, slave, path = _pty()
    dump = tmp_path / "dump.txt"
    transport = create_transport(f"spy://{path}?file={dump}")
    try:
        transport.open()
        transport.write(b"BEFORE\x00")
        _read_master(master, 7)
        transport.close()  # the link lost: the client closes and opens again
        transport.open()
        transport.write(b"AFTER\x00")
        _read_master(master, 6)
    finally:
        transport.close()
        os.close(master)
        os.close(slave)
    text = dump.read_text()
    assert "BEFORE" in text and "AFTER" in text
    assert text.index("BEFORE") < text.index("AFTER")


def test_a_raw_spy_to_stderr_writes_the_bytes_there():
    master, slave, path = _pty()
    try:
        code = (
            "import sys; from hil.link.transports import create_transport\n"
            f"t = create_transport('spy://{path}?raw').open(); t.write(b'\\x01\\xfe\\x00'); t.close()\n"
        )
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=60)
        assert done.returncode == 0, done.stderr.decode(errors="replace")
        assert done.stderr == b"\x01\xfe\x00"
    finally:
        os.close(master)
        os.close(slave)
