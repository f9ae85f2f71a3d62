"""A run's phone, picked by URL through one registry like the board's transports.

=================================  =====================================================================
URL                                phone source
=================================  =====================================================================
``udp://HOST:PORT``                SensaGram's JSON datagrams, one per sensor event, received live
                                   (:mod:`.listening`, :mod:`.phone_udp`)
``http://HOST:PORT[/PATH]``        Sensor Logger's HTTP Push batches, received live
                                   (:mod:`.listening`, :mod:`.phone_push`)
``HOST:PORT``                      the same as ``udp://HOST:PORT``
``recording://``                   the log ``hil replay`` plays, on the run's clock (:mod:`.recorded`)
``sim://``                         the built-in emulator's simulated world: in-process in lockstep,
                                   streamed over UDP on loopback in real time (:mod:`.simulated`)
=================================  =====================================================================

Every source has one shape (:class:`~.base.PhoneSource`: ``drain(now)``, ``truth(now)``, ``close()``, and
what the runtime asks of any source), so the runtime builds each the same way: :func:`create_source` with
the run's :class:`~.base.SourceContext`. For a live stream the host *listens* on the URL (port 0 picks a
free one); the emulator's simulated phone *streams* to it (:func:`open_sender`), exactly as the app would,
so the live path is the one a real phone uses. ``docs/formats.md`` says how to set up each app.

As with the transports (:mod:`hil.link.transports`) and the estimators (:mod:`hil.estimation.registry`),
the schemes ``hil`` ships are in its table and each maps to ``"module:factory"`` (a
:data:`~.base.SourceFactory`: it takes the URL and the context and returns the source, open), imported on
first use; another package adds a scheme as an entry point in the group ``vscmg_hil.phone_sources``
whose name is the scheme, in its ``pyproject.toml``::

    [project.entry-points."vscmg_hil.phone_sources"]
    myrig = "mypackage.phone:open_rig"

:func:`register` adds one at run time.
"""

from __future__ import annotations

from urllib.parse import urlsplit

from hil.link.sources.base import (
    GroundTruth,
    PhoneSource,
    SenderEvent,
    SenderStatus,
    SourceContext,
    SourceFactory,
)
from hil.link.sources.listening import ListeningSource, open_receiver, open_sender, phone_url
from hil.link.sources.stream import PhoneReceiver, PhoneSender, StreamStats
from hil.plugins import Registry
from protocol.errors import ConfigError

ENTRY_POINT_GROUP = "vscmg_hil.phone_sources"
DEFAULT_PHONE_URL = "udp://127.0.0.1:8123"

# scheme -> "module:factory": hil's own, then the installed entry points and register().
_REGISTRY = Registry(
    ENTRY_POINT_GROUP,
    {
        "udp": "hil.link.sources.listening:listen",
        "http": "hil.link.sources.listening:listen",
        "recording": "hil.link.sources.recorded:play",
        "sim": "hil.link.sources.simulated:simulated_phone",
    },
)


def register(scheme: str, target: str) -> None:
    """Add (or replace) the phone source for ``scheme``; ``target`` is ``"module:factory"``."""
    _REGISTRY.register(scheme, target)


def schemes() -> list[str]:
    return _REGISTRY.names()


def source_url(address: str) -> str:
    """``address`` as a phone-source URL: a bare ``HOST:PORT`` is SensaGram's ``udp://HOST:PORT``."""
    return address if "://" in address else f"udp://{address}"


def create_source(address: str, context: SourceContext, where: str = "--phone") -> PhoneSource:
    """The phone source for ``address`` (see the module docstring), open. A scheme nobody registered, or
    a factory that cannot be imported, is a :class:`ConfigError` naming ``where`` (and the known schemes);
    a source that cannot open (a busy port) raises its own error."""
    url = source_url(address)
    try:
        scheme = urlsplit(url).scheme.lower()
    except ValueError as exc:  # urllib's own refusal of the address (an unbalanced '[')
        raise ConfigError(f"{address!r}: not a URL ({exc})", where) from exc
    target = _REGISTRY.target(scheme)
    if target is None:
        why = f"unknown phone source scheme {scheme!r} (known: {', '.join(schemes())})"
        raise ConfigError(f"{address!r}: {why}", where)
    try:
        factory: SourceFactory = _REGISTRY.load(target)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{address!r}: phone source {target} is not available: {exc}", where) from exc
    return factory(url, context)


__all__ = [
    "DEFAULT_PHONE_URL",
    "ENTRY_POINT_GROUP",
    "GroundTruth",
    "ListeningSource",
    "PhoneReceiver",
    "PhoneSender",
    "PhoneSource",
    "SenderEvent",
    "SenderStatus",
    "SourceContext",
    "SourceFactory",
    "StreamStats",
    "create_source",
    "open_receiver",
    "open_sender",
    "phone_url",
    "register",
    "schemes",
]
