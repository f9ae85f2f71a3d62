"""A user's transport, held to its interface: :class:`CheckedTransport` wraps a transport that another
package registered (:func:`hil.link.transports.create_transport` builds every scheme but ``hil``'s and
``firmware_sim``'s through it), so that whatever it does wrong ends the run with a
:class:`~hil.plugins.PluginError` naming it, what it did and when — never a traceback from the reader
thread or the deframer.

What is checked, each call: ``read`` returns ``bytes`` (a ``bytearray`` or ``memoryview`` is passed on as
bytes; a ``str``, ``None`` or anything else is refused), ``present`` None or a bool, ``heard_instead`` a
string. What the transport raises of the project's own (a :class:`~protocol.errors.LinkError` for a port
that vanished, a ``TransportError`` for one that cannot open: the interface's way of saying so, which the
board client answers by reconnecting) passes as it is; anything else (its own exception, Python's, a
``sys.exit()`` in the reader thread) becomes a :class:`~hil.plugins.PluginError` ``from`` it
(:func:`~hil.plugins.call_plugin`), naming the call (``read #57``, and the bytes read before it). Ctrl-C
(KeyboardInterrupt) passes through. A backend's ``counters()`` (``summary.json``'s ``link.transport``) is
checked as the rest: a dict keyed by strings, JSON; other attributes the wrapper does not know are the
inner transport's."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from hil.plugins import PluginError, call_plugin, describe_value, json_plain
from protocol.errors import HilError

from .base import Transport


class CheckedTransport(Transport):
    """``inner``, a user's :class:`~.base.Transport`, with every call checked (see the module docstring);
    ``name`` is its registered scheme, for the errors."""

    def __init__(self, inner: Transport, name: str) -> None:
        super().__init__(inner.url)
        self.inner = inner
        self.name = name
        self.plugin = f"transport {name!r}"
        self.reads = 0

    def __repr__(self) -> str:
        return f"CheckedTransport({self.inner!r}, {self.name!r})"

    def __getattr__(self, name: str) -> Any:  # only for what the wrapper has not: the inner's own
        if name == "inner":  # not set yet (unpickled, half built): no recursion
            raise AttributeError(name)
        return getattr(self.inner, name)

    def _call(self, what: str, call: Callable[[], Any]) -> Any:
        # the project's own (a LinkError: the port vanished) passes as raised
        return call_plugin(self.plugin, what, call, HilError)

    @property
    def is_open(self) -> bool:
        return bool(self._call("is_open", lambda: self.inner.is_open))

    def open(self) -> Transport:
        self._call(f"open of {self.url}", self.inner.open)
        return self

    def read(self, timeout: float | None = 0.05) -> bytes:
        self.reads += 1
        where = f"read #{self.reads} (after {self.bytes_in} bytes in)"
        data = self._call(where, lambda: self.inner.read(timeout))
        if type(data) is not bytes:
            if not isinstance(data, (bytes, bytearray, memoryview)):
                raise PluginError(self.plugin, f"{where} returned {describe_value(data)}, not bytes")
            data = bytes(data)
        self.bytes_in += len(data)
        return data  # type: ignore[no-any-return]

    def write(self, data: bytes) -> None:
        self._call(f"write of {len(data)} bytes (after {self.bytes_out} out)", lambda: self.inner.write(data))
        self.bytes_out += len(data)

    def close(self) -> None:
        self._call("close", self.inner.close)

    def present(self) -> bool | None:
        found = self._call("present", self.inner.present)
        if found is not None and not isinstance(found, bool):
            raise PluginError(self.plugin, f"present returned {describe_value(found)}, not None or a bool")
        return found  # type: ignore[no-any-return]

    def heard_instead(self) -> str:
        said = self._call("heard_instead", self.inner.heard_instead)
        if not isinstance(said, str):
            raise PluginError(self.plugin, f"heard_instead returned {describe_value(said)}, not a string")
        return said

    def counters(self) -> dict[str, Any]:
        """The inner transport's own counters (a backend's: ``summary.json``'s ``link.transport``), a plain
        copy; {} for one that keeps none. Forwarded unchecked, a ``counters()`` that raised or returned no
        mapping crashed the run's ending, no summary.json written."""
        counters = self._call("counters", lambda: getattr(self.inner, "counters", None))
        if counters is None:
            return {}
        found = self._call("counters", counters)
        return self._call("counters: reading what it returned", lambda: self._counters(found))  # type: ignore[no-any-return]

    def _counters(self, found: Any) -> dict[str, Any]:
        if not isinstance(found, Mapping):
            raise PluginError(self.plugin, f"counters returned {describe_value(found)}, not a dict")
        try:
            plain: dict[str, Any] = json_plain(dict(found))
        except (TypeError, ValueError) as exc:
            raise PluginError(self.plugin, f"counters returned what summary.json cannot hold: {exc}") from exc
        return plain

    # the template's backend: unused (the public calls above go to the inner transport's own)
    def _open_impl(self) -> None:
        self.open()

    def _read(self, timeout: float | None) -> bytes:
        return self.read(timeout)

    def _write(self, data: bytes) -> None:
        self.write(data)

    def _close(self) -> None:
        self.close()
