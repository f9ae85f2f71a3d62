"""The board client's configuration: :class:`ClientConfig` (retry policies, heartbeat, setpoint rate,
silence, reconnection, queues), its checks, and the identity the host announces (:data:`HOST_IDENTITY`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from protocol.aoa import AccessoryIdentity
from protocol.errors import ConfigError
from protocol.messages import SCHEMA_HASH
from protocol.reliable import RetryPolicy

_U32 = 1 << 32


HOST_IDENTITY = AccessoryIdentity("vscmg-hil", "hil host", "vscmg-hil host runtime", "0.1.0")
"""The AOA identity strings this host announces in ``Hello`` by default (the board may log them)."""


@dataclass(frozen=True)
class ClientConfig:
    """Everything that shapes the board client; times in seconds.

    ``commands`` is the retry policy of Arm/Disarm/SetMode/calibration fragments (default: 5 tries,
    100 ms apart). ``handshake`` is Hello's: more tries (a booting board drops bytes while in reset, and
    the handshake's ~200 bytes are the likeliest to be hit on a noisy link). ``schema_hash`` is what this
    host announces: the catalogue it was built with; a test changes it to play a host built against
    another catalogue. Reconnection: the first retry ``reconnect_first_s`` after the loss, each next one
    twice as late up to ``reconnect_max_s``; after ``reconnect_give_up_s`` (None: never) the client
    raises :class:`LinkError`. ``rearm_on_reconnect``: after a reconnect, arm again if the host had armed
    the board (off by default — the host never re-arms unless asked). ``event_queue``: events held for
    :meth:`BoardClient.drain_events` (older ones are dropped and counted when nobody drains them).
    ``download_idle_s``: a calibration download no fragment has come for in this long fails
    (:class:`LinkTimeout`) — the board resends an unacknowledged fragment 5 times 0.1 s apart, then gives
    the transfer up, and a caller without a timeout waited for ever.
    """

    identity: AccessoryIdentity = HOST_IDENTITY
    schema_hash: int = SCHEMA_HASH
    commands: RetryPolicy = field(default_factory=RetryPolicy)
    handshake: RetryPolicy = field(default_factory=lambda: RetryPolicy(timeout_s=0.1, max_tries=50))
    heartbeat_period_s: float = 0.05
    max_setpoint_rate_hz: float | None = None
    silence_after_s: float = 1.0
    rtt_samples: int = 1024
    reconnect_first_s: float = 0.05
    reconnect_max_s: float = 2.0
    reconnect_give_up_s: float | None = 60.0
    rearm_on_reconnect: bool = False
    event_queue: int = 10_000
    max_block_s: float = 0.05
    download_idle_s: float = 2.0

    def __post_init__(self) -> None:
        for name in _POSITIVE + _POSITIVE_OR_NONE:
            value = getattr(self, name)
            if value is not None or name in _POSITIVE:
                _check_positive(value, f"ClientConfig.{name}")
        if self.reconnect_max_s < self.reconnect_first_s:
            raise ConfigError("must be >= reconnect_first_s", "ClientConfig.reconnect_max_s")
        for name in ("rtt_samples", "event_queue"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{value!r} must be an integer >= 1", f"ClientConfig.{name}")
        if not 0 <= self.schema_hash < _U32:
            raise ConfigError(f"{self.schema_hash!r} is not a u32", "ClientConfig.schema_hash")

    def reconnect_delay(self, attempt: int) -> float:
        """Seconds before reconnection attempt ``attempt`` (0, 1, 2, ...): doubling, bounded."""
        return min(self.reconnect_first_s * 2.0 ** min(attempt, 60), self.reconnect_max_s)


_POSITIVE = (
    "heartbeat_period_s",
    "silence_after_s",
    "reconnect_first_s",
    "reconnect_max_s",
    "max_block_s",
    "download_idle_s",
)
_POSITIVE_OR_NONE = ("max_setpoint_rate_hz", "reconnect_give_up_s")


def _check_positive(value: object, where: str) -> None:
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not (number and math.isfinite(value) and value > 0):  # type: ignore[arg-type,operator]
        raise ConfigError(f"{value!r} must be a finite number > 0", where)
