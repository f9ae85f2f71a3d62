"""Who may read the downlink and send the uplink: where the server listens, the access token, and the
checks every request passes (docs/gcs.md, "Security").

- **Loopback by default.** ``--gcs`` alone listens on 127.0.0.1; another address only when the user names
  one (``--gcs 0.0.0.0:8470``), and the CLI then says that anyone who can reach it with the token can
  command the board.
- **A token**, random per server (``secrets.token_urlsafe``), printed inside the page's URL as Jupyter does.
  Every ``/api/`` request carries it (the stream in its query, a command in its ``Authorization`` header);
  it is compared in constant time.
- **Origin**: a command whose ``Origin`` header is not the page's own origin is refused (a page on another
  site cannot command the board through the user's browser). A request without ``Origin`` (a script,
  ``curl``) needs the token alone.
- **Host**: on a loopback server the ``Host`` header must name a loopback host (against DNS rebinding, where
  a foreign name is made to resolve to 127.0.0.1).
"""

from __future__ import annotations

import hmac
import ipaddress
import re
import secrets
from dataclasses import dataclass

from protocol.errors import ConfigError

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8470
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
# A Host header (RFC 9110 uri-host [":" port], as a browser or a script writes one): a name or IPv4 address,
# or an IPv6 address in brackets, and an optional port of digits.
_HOST = re.compile(r"(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<name>[A-Za-z0-9._-]+))(?::(?P<port>[0-9]{1,5}))?")


def parse_bind(text: str | None) -> tuple[str, int, bool]:
    """``(host, port, explicit_port)`` from ``HOST:PORT``, ``:PORT``, ``PORT``, ``HOST`` or ``[V6]:PORT``;
    None or empty: the loopback default. Port 0 asks the kernel for a free one. ConfigError otherwise."""
    where = "--gcs"
    if not text:
        return DEFAULT_HOST, DEFAULT_PORT, False
    text = text.strip()
    host, port_text = DEFAULT_HOST, ""
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise ConfigError(f"unclosed [ in {text!r} (an IPv6 address is written [::1]:8470)", where)
        host, rest = text[1:end], text[end + 1 :]
        if rest and not rest.startswith(":"):
            raise ConfigError(f"expected :PORT after the address in {text!r}", where)
        port_text = rest[1:]
    elif text.count(":") == 1:
        head, port_text = text.split(":")
        host = head or DEFAULT_HOST
    elif text.isdigit():
        port_text = text
    elif ":" in text:
        raise ConfigError(f"write an IPv6 address in brackets, e.g. [{text}]:{DEFAULT_PORT}", where)
    else:
        host = text
    if not port_text:
        return host, DEFAULT_PORT, False
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise ConfigError(f"the port must be a number 0-65535, got {port_text!r}", where)
    return host, int(port_text), True


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or an address) is this machine's loopback."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    """A fresh access token (128 random bits, URL-safe)."""
    return secrets.token_urlsafe(16)


def url_host(host: str) -> str:
    """``host`` as it is written in a URL (IPv6 in brackets; the wildcard as the loopback address)."""
    if host in ("", "0.0.0.0"):
        return DEFAULT_HOST
    if host == "::":
        return "[::1]"
    return f"[{host}]" if ":" in host else host


@dataclass(frozen=True)
class Access:
    """The checks for one server listening on ``host``:``port`` with ``token``."""

    token: str
    host: str
    port: int

    @property
    def loopback(self) -> bool:
        return is_loopback(self.host)

    def token_ok(self, given: str | None) -> bool:
        """Constant-time comparison of a presented token."""
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def host_ok(self, host_header: str | None) -> bool:
        """On a loopback server, the ``Host`` header must be a loopback name (and this port)."""
        if not self.loopback:
            return True
        if not host_header:
            return False
        name, port = _split_host(host_header)
        return is_loopback(name) and (port is None or port == self.port)

    def origin_ok(self, origin: str | None, host_header: str | None) -> bool:
        """A browser's ``Origin`` must be this server as the page reached it (``http://`` + the ``Host``
        header); no ``Origin`` at all (not a browser) passes, the token still being required."""
        if origin is None:
            return True
        if not host_header:
            return False
        scheme, _, o_host = origin.strip().partition("://")
        if scheme != "http":
            return False
        o_name, o_port = _split_host(o_host)  # a browser's Origin is "http://" + the host it reached
        h_name, h_port = _split_host(host_header)
        if not o_name or not h_name:
            return False
        return o_name.lower() == h_name.lower() and (o_port or 80) == (h_port or 80)


def _split_host(header: str) -> tuple[str, int | None]:
    """``(name, port)`` of a ``Host`` header (``[::1]:8470``, ``localhost:8470``, ``example.org``); a
    malformed one (``[::1``, ``[zz]:1``, ``[::1]]``, a port past 65535) is ``("", -1)``, which matches no
    name and no port. Parsed by :data:`_HOST`, not ``urlsplit``, which raises ValueError for some malformed
    headers (a 500 out of the check, where the header is the client's to write and the answer a 403) and
    takes others (``[::1]]`` as ``::1``)."""
    m = _HOST.fullmatch(header.strip())
    if m is None:
        return "", -1
    name = m["v6"] if m["v6"] is not None else m["name"]
    if m["v6"] is not None:
        try:
            ipaddress.IPv6Address(name)
        except ValueError:
            return "", -1
    port = None if m["port"] is None else int(m["port"])
    return (name, port) if port is None or port <= 65535 else ("", -1)
