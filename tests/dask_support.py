"""What the tests that start a real ``dask scheduler`` and ``dask worker`` share: a free loopback port and
the environment their processes run in (this one's, without its ``DASK_*`` settings)."""

from __future__ import annotations

import os
import socket


def free_port() -> int:
    """A TCP port on the loopback no process listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def dask_env(**extra: str) -> dict[str, str]:
    """This process's environment without its ``DASK_*`` settings (a scheduler or worker of a test keeps
    Dask's defaults), bytecode not written, and ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    return {**env, "PYTHONDONTWRITEBYTECODE": "1", **extra}
