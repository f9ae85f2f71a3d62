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

A scheme ``hil`` does not ship is held to the interface (:class:`~.checked.CheckedSource`): what its
source's ``drain`` hands over must be a list of :class:`~hil.estimation.sensors.SensorSample` of real
numbers, its ``truth`` None or a finite rotation and rate, and so on for each method; whatever it gets
wrong, or raises of its own (not the project's :class:`~protocol.errors.HilError`), in its factory or
mid-run, is a :class:`~hil.plugins.PluginError` naming the scheme, what it did and when, and the run
ends on it as an error (exit status 2, one line), its board disarmed. Samples of the right types but
absurd (NaN, out of range, out of order, repeated) are the host's admission policy's to drop and count
(:mod:`hil.estimation.admission`), as a live phone's are. ``hil``'s own schemes are not wrapped.
"""

from __future__ import annotations

import contextlib
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
from hil.plugins import PluginError, Registry, call_plugin
from protocol.errors import ConfigError, HilError

ENTRY_POINT_GROUP = "vscmg_hil.phone_sources"
DEFAULT_PHONE_URL = "udp://127.0.0.1:8123"

# scheme -> "module:factory": hil's own, then the installed entry points and register().
_BUILT_IN = {
    "udp": "hil.link.sources.listening:listen",
    "http": "hil.link.sources.listening:listen",
    "recording": "hil.link.sources.recorded:play",
    "sim": "hil.link.sources.simulated:simulated_phone",
}
_REGISTRY = Registry(ENTRY_POINT_GROUP, _BUILT_IN)
_BUILT_IN_TARGETS = frozenset(_BUILT_IN.values())  # hil's own sources: not wrapped (CheckedSource)


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
    a source that cannot open (a busy port) raises its own error. A scheme ``hil`` does not ship is built
    wrapped in a :class:`~.checked.CheckedSource`; its factory raising anything but the project's own
    errors, or returning what is not a :class:`PhoneSource`, is a :class:`~hil.plugins.PluginError`."""
    url = source_url(address)
    try:
        urlsplit(url)
    except ValueError as exc:  # urllib's own refusal of the address (an unbalanced '[')
        raise ConfigError(f"{address!r}: not a URL ({exc})", where) from exc
    # what comes before "://", as the transports read theirs: urllib's scheme is '' for one with a "_"
    # (not RFC 3986's), so a plugin registered as "my_rig" was listed as known and never reached
    scheme = url.split("://", 1)[0].lower()
    target = _REGISTRY.target(scheme)
    if target is None:
        why = f"unknown phone source scheme {scheme!r} (known: {_REGISTRY.known()})"
        raise ConfigError(f"{address!r}: {why}", where)
    try:
        factory: SourceFactory = _REGISTRY.load(target)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{address!r}: phone source {target} is not available: {exc}", where) from exc
    if target in _BUILT_IN_TARGETS:
        return factory(url, context)
    from hil.link.sources.checked import CheckedSource

    plugin = f"phone source {scheme!r}"
    # the project's own (a ConfigError naming an option, a busy port) passes as raised
    built = call_plugin(plugin, f"its factory {target}", lambda: factory(url, context), HilError)
    if not isinstance(built, PhoneSource):
        with contextlib.suppress(HilError):  # what it opened is released, whatever it is
            call_plugin(plugin, "close", lambda: _close_any(built))
        raise PluginError(plugin, f"its factory {target} returned {type(built).__name__}, not a PhoneSource")
    return CheckedSource(built, scheme)


def _close_any(built: object) -> None:
    close = getattr(built, "close", None)
    if callable(close):
        close()


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
