"""A phone address that names no port, or one nothing could reach: ``--phone http://127.0.0.1:99999/`` (and
a port that is no number) was quietly taken for the default port; firmware-sim's ``--phone
udp://127.0.0.1:99999`` (``udp://:8123``, ``:-1``) ended in a LinkError traceback from outside its error
handling, its pty server left open; ``--phone udp://127.0.0.1:0`` and ``udp://[::1]:8123`` were accepted
and every datagram then failed, only counted. Each is now a :class:`ConfigError` naming ``--phone`` (and the
port), exit status 2, at start.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.cli import main as hil_main
from hil.link.sources.phone_udp import PhoneUdpSender
from hil.link.sources.stream import split_url
from protocol.errors import ConfigError, LinkError

UDP = ("udp", "udp://HOST:PORT", None)
HTTP = ("http", "http://HOST:PORT/PATH", 80)


@pytest.mark.parametrize("scheme", [UDP, HTTP], ids=["udp", "http"])
@pytest.mark.parametrize("port", ["99999", "65536", "-1", "abc", "+5", "0x10", "1e3", "٣"])
def test_a_port_that_is_no_port_number_is_an_error_naming_it(scheme, port):
    name, form, default = scheme
    url = f"{name}://127.0.0.1:{port}/"
    with pytest.raises(ConfigError) as caught:
        split_url(url, name, form, default)
    assert caught.value.where == "--phone"
    assert f"port {port!r} is not a port number 0..65535" in caught.value.detail
    assert form in caught.value.detail


@given(port=st.text(min_size=1, max_size=8).filter(lambda p: not set(p) & set("/?#@")))
def test_any_port_text_is_the_number_it_says_or_an_error_never_the_default(port):
    url = f"http://127.0.0.1:{port}/"
    valid = port.isascii() and port.isdigit() and int(port) <= 65535
    try:
        host, got, _ = split_url(url, "http", "http://HOST:PORT/PATH", 80)
    except (ConfigError, ValueError) as exc:
        assert isinstance(exc, ConfigError) and exc.where == "--phone"
        assert not valid
        return
    assert valid and got == int(port)  # never 80 for a port that was given


def test_a_listener_may_pick_port_0_a_sender_may_not():
    assert split_url("udp://127.0.0.1:0", *UDP)[1] == 0
    with pytest.raises(ConfigError, match="port 0 picks a free port only where hil listens"):
        split_url("udp://127.0.0.1:0", *UDP, sending=True)


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("udp://127.0.0.1:0", "port 0"),
        ("udp://[::1]:8123", "an IPv6 address"),
        ("udp://:8123", "must be udp://HOST:PORT"),
        ("udp://127.0.0.1", "must be udp://HOST:PORT"),
        ("udp://127.0.0.1:99999", "port '99999'"),
        ("udp://nosuchhost.invalid:8123", "no IPv4 address for 'nosuchhost.invalid'"),
    ],
)
def test_the_udp_sender_refuses_an_address_no_datagram_could_reach(url, said):
    with pytest.raises(ConfigError, match=said) as caught:
        PhoneUdpSender(url)
    assert caught.value.where == "--phone"


def test_the_udp_sender_resolves_a_name_once():
    from hil.link.sources.phone_udp import sender_address

    assert sender_address("udp://localhost:8123") == ("127.0.0.1", 8123)
    sender = PhoneUdpSender("udp://127.0.0.1:9")
    sender.close()


@pytest.mark.parametrize(
    ("phone", "said"),
    [
        ("udp://127.0.0.1:99999", "port '99999' is not a port number"),
        ("udp://:8123", "must be udp://HOST:PORT"),
        ("udp://127.0.0.1:-1", "port '-1' is not a port number"),
        ("udp://127.0.0.1:0", "port 0 picks a free port only where hil listens"),
        ("udp://[::1]:8123", "::1 is an IPv6 address"),
        ("http://127.0.0.1:0/", "port 0 picks a free port only where hil listens"),
        ("http://127.0.0.1:abc/", "port 'abc' is not a port number"),
        ("http://127.0.0.1:[/", "not a URL (Invalid IPv6 URL)"),
    ],
)
def test_firmware_sim_refuses_a_phone_address_at_start(phone, said):
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_sim",
            "--duration",
            "0.5",
            "--world",
            "cubesat-1u",
            "--phone",
            phone,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stdout == ""  # no pty path announced: nothing was served
    assert done.stderr.startswith("firmware-sim: error: --phone: ")
    assert said in done.stderr


def test_firmware_sim_closes_its_server_when_the_world_s_phone_cannot_start(monkeypatch, capsys):
    """A sender failing as it starts (here: a LinkError from the world's streamer) is the start-up's error,
    status 2, said in one line, and the pty server already made is closed, not left open."""
    import firmware_sim.cli as cli
    from firmware_sim.servers.pty_server import PtyServer
    from firmware_sim.world import world as world_module

    closed = []
    real_close = PtyServer.close

    def close(self: PtyServer) -> None:
        closed.append(self.path)
        real_close(self)

    def refuse(*args: object, **kwargs: object) -> None:
        raise LinkError("the phone's socket cannot be opened")

    monkeypatch.setattr(PtyServer, "close", close)
    monkeypatch.setattr(world_module.WorldStreamer, "__init__", refuse)
    assert cli.main(["--world", "cubesat-1u", "--duration", "0.5"]) == 2
    err = capsys.readouterr().err
    assert "firmware-sim: error: the phone's socket cannot be opened" in err
    assert len(closed) == 1


@pytest.mark.parametrize(
    "phone", ["http://127.0.0.1:99999/", "http://127.0.0.1:abc/", "udp://127.0.0.1:65536"]
)
def test_hil_run_refuses_a_phone_port_that_is_no_number(tmp_path, capsys, phone):
    status = hil_main(
        [
            "run",
            "--port",
            "emu://",
            "--phone",
            phone,
            "--phone-wait",
            "1",
            "--no-plots",
            "--out",
            str(tmp_path),
        ]
    )
    assert status == 2
    err = capsys.readouterr().err
    assert "--phone:" in err and "is not a port number 0..65535" in err
    assert "127.0.0.1:80/" not in err  # not the default port
