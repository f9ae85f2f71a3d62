"""Nothing the tools start listens beyond loopback unless the user asks for it (issue 16, finding 6: the
Dask dashboard of ``hil montecarlo`` listened on 0.0.0.0 without authentication)."""

from __future__ import annotations

import socket

from hil.montecarlo.campaign import open_client


def test_the_local_clusters_dashboard_listens_on_loopback_only():
    with open_client(workers=1, processes=False) as client:
        server = client.cluster.scheduler.http_server  # the dashboard (bokeh) and the scheduler's HTTP
        bound = [sock.getsockname()[:2] for sock in server._sockets.values()]
        assert bound and all(host == "127.0.0.1" for host, _ in bound)
        port = bound[0][1]
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass  # it serves there
        for address in _other_addresses():
            probe = socket.socket()
            probe.settimeout(1.0)
            try:
                assert probe.connect_ex((address, port)) != 0, f"the dashboard answers on {address}"
            finally:
                probe.close()


def _other_addresses() -> list[str]:
    """This machine's non-loopback IPv4 addresses (none in some sandboxes)."""
    try:
        infos = socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET)
    except OSError:
        return []
    return sorted({info[4][0] for info in infos if not info[4][0].startswith("127.")})
