"""The first handshake with a board, tried again while its port comes back: :func:`connect_within`.

Before a session is up, :meth:`BoardClient.connect` tries once: the client's own reconnection (a doubling
back-off, :meth:`ClientConfig.reconnect_delay`) only starts once it has had a session to lose. Yet a port
may vanish or refuse to open *at* the first handshake for a reason that passes — a board unplugged and
plugged back, a ``firmware-sim`` restarting on its ``--link``, one killed after it opened but before it
answered. Every tool that connects to a board (``hil run`` and ``hil replay --port`` through the runtime,
``hil calibrate esc | sweep | unit``) connects through this one function, each with its own bound and its
own way of saying each retry (an ``events.jsonl`` record, a line on stderr).

What is tried again: any :class:`LinkError` but those no second try can mend, which are raised at once —
:class:`TransportRefused` (the URL describes no board, or another host holds the port: :class:`PortBusy`),
:class:`LinkTimeout` (a port that answers nothing) and :class:`HandshakeError` (a board of another
protocol). The time is the client's clock: in lockstep the back-off advances simulated time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from protocol.errors import HandshakeError, LinkError, LinkTimeout, TransportError, TransportRefused

from .client import BoardClient
from .events import BoardInfo


@dataclass(frozen=True)
class ConnectRetry:
    """One failed try of the first handshake, about to be tried again.

    ``attempt``: 0 for the first retry, then 1, 2, ...; ``t``: the client's clock when it failed (s);
    ``delay_s``: the back-off before the next try (s); ``waited_s``: time since the first try (s);
    ``error``: what the try raised."""

    attempt: int
    t: float
    delay_s: float
    waited_s: float
    error: LinkError


def connect_within(
    client: BoardClient, within_s: float, on_retry: Callable[[ConnectRetry], None] | None = None
) -> BoardInfo:
    """Connect ``client`` (:meth:`BoardClient.connect`), trying again with the client's back-off while
    the port cannot be opened or vanishes under the handshake, for up to ``within_s`` seconds of its
    clock; ``on_retry`` is called before each wait. Raises what cannot be mended at once (see the module),
    else, once ``within_s`` has passed, a :class:`TransportError` saying how long it tried. A failed try
    leaves the transport closed (:meth:`BoardClient.connect`); an interrupt (``KeyboardInterrupt``) goes
    through as it is, the caller closing the client."""
    clock = client.clock
    start = clock.now()
    attempt = 0
    while True:
        try:
            return client.connect()
        except (TransportRefused, LinkTimeout, HandshakeError):  # no board, not ours, or not free: at once
            raise
        except LinkError as exc:  # could not open, or vanished under the handshake
            now = clock.now()
            if now - start >= within_s:
                raise TransportError(f"{exc} (tried for {now - start:.1f} s)") from exc
            delay = client.config.reconnect_delay(attempt)
            if on_retry is not None:
                on_retry(ConnectRetry(attempt, now, delay, now - start, exc))
            clock.sleep_until(now + delay)
            attempt += 1
