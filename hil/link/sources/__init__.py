"""Live phone sources, picked by URL like the board's transports.

=================================  =====================================================================
``udp://HOST:PORT``                SensaGram's JSON datagrams, one per sensor event (:mod:`.phone_udp`)
``http://HOST:PORT[/PATH]``        Sensor Logger's HTTP Push batches (:mod:`.phone_push`)
``HOST:PORT``                      the same as ``udp://HOST:PORT``
=================================  =====================================================================

The host *listens* on the URL (:func:`open_receiver`; port 0 picks a free one); the emulator's simulated
phone *streams* to it (:func:`open_sender`), exactly as the app would, so the live path is the one a real
phone uses. ``docs/formats.md`` says how to set up each app.
"""

from __future__ import annotations

from urllib.parse import urlsplit

from hil.link.sources.stream import PhoneReceiver, PhoneSender, StreamStats
from protocol.errors import ConfigError

DEFAULT_PHONE_URL = "udp://127.0.0.1:8123"

__all__ = ["DEFAULT_PHONE_URL", "PhoneReceiver", "PhoneSender", "StreamStats", "open_receiver",
           "open_sender", "phone_url"]  # fmt: skip


def phone_url(address: str, where: str = "--phone") -> str:
    """``address`` as a phone-stream URL: a bare ``HOST:PORT`` becomes ``udp://HOST:PORT``; a scheme other
    than udp or http is a :class:`ConfigError` naming ``where``."""
    url = address if "://" in address else f"udp://{address}"
    scheme = urlsplit(url).scheme
    if scheme not in ("udp", "http"):
        raise ConfigError(f"{address!r}: a phone stream is udp://HOST:PORT or http://HOST:PORT/PATH", where)
    return url


def open_receiver(address: str) -> PhoneReceiver:
    """Listen for a phone stream at ``address`` (see :func:`phone_url`); a busy or bad address is a
    :class:`~protocol.errors.LinkError`."""
    url = phone_url(address)
    if url.startswith("http://"):
        from hil.link.sources.phone_push import PhonePushServer

        return PhonePushServer(url)
    from hil.link.sources.phone_udp import PhoneUdpReceiver

    return PhoneUdpReceiver(url)


def open_sender(address: str) -> PhoneSender:
    """Stream a (simulated) phone to ``address`` the way its app does."""
    url = phone_url(address)
    if url.startswith("http://"):
        from hil.link.sources.phone_push import PhonePushSender

        return PhonePushSender(url)
    from hil.link.sources.phone_udp import PhoneUdpSender

    return PhoneUdpSender(url)
