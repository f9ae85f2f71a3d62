"""A ground station whose first read is refused gives back what it bound. ``GroundStation`` binds its
server, then reads its source once before it serves; a refused first read (a FIFO where a run's telemetry
goes, a path that is no directory) raised with the listening socket and the server's event loop left to
the garbage collector: the port stayed taken, so ``hil gcs`` tried again in the same process on the same
``--bind`` was refused "address in use"."""

from __future__ import annotations

import gc
import os
import socket
from pathlib import Path

import pytest

from hil.gcs.station import GroundStation
from protocol.errors import InputFormatError


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def refused_run_dir(tmp_path: Path, how: str) -> Path:
    run = tmp_path / how
    if how == "fifo":
        run.mkdir()
        os.mkfifo(run / "telemetry.csv")
    elif how == "file":
        run.write_text("not a directory\n")
    return run


@pytest.mark.parametrize("how", ["fifo", "file", "missing"])
def test_a_refused_first_read_frees_the_port(tmp_path, how):
    port = free_port()
    bind = f"127.0.0.1:{port}"
    good = tmp_path / "good"
    good.mkdir()
    (good / "telemetry.csv").write_text("t,x\n0.0,1.0\n")
    gc.disable()  # the collector would have freed the socket: the station must, at once
    try:
        with pytest.raises(InputFormatError):
            GroundStation.replay(refused_run_dir(tmp_path, how), bind=bind, follow=False)
        with GroundStation.replay(good, bind=bind, follow=False) as station:
            assert station.port == port
    finally:
        gc.enable()
