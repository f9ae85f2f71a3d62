"""``hil run --port`` against ``firmware-sim --world cubesat-1u`` on a real pty, signalled at drawn moments
— the handshake, the wait for the phone, the warm-up, spin-up and slew — with SIGINT, SIGTERM or SIGHUP
(a closed terminal), maybe followed at once by a second one: the run ends, its run directory is honest and
the board the host armed is left DISARMED by the host, never by its own link watchdog (its log's last state
change ``ARMED -> DISARMED``, not ``ARMED -> FAILSAFE``). SIGHUP once ended the run at once, the board
spinning until its watchdog tripped. Helpers from tests/test_sigterm.py (firmware-sim with its log) and
tests/test_run_ends_signals.py (what every run directory must be).
"""

from __future__ import annotations

import signal
import socket
import time
from pathlib import Path

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from test_run_ends_signals import NAMES, _disarms, _ended, _honest_run_dir, interrupted_by
from test_sigterm import (
    _board_disarmed_by_the_host,
    _kinds,
    _run_dir,
    _spawn,
    _text,
    _wait_until,
    firmware_sim,
)

MOMENTS = ("handshake", "phone_wait", "armed", "spin_up", "slew_start")


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@given(
    first=st.sampled_from(sorted(NAMES)),
    moment=st.sampled_from(MOMENTS),
    delay=st.floats(0.0, 0.5),
    second=st.none() | st.tuples(st.sampled_from(sorted(NAMES)), st.floats(0.0, 0.005)),
)
@example(first=signal.SIGHUP, moment="spin_up", delay=0.2, second=None)
@example(first=signal.SIGTERM, moment="phone_wait", delay=0.3, second=(signal.SIGINT, 0.001))
@settings(
    max_examples=2,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
def test_a_signalled_port_run_leaves_the_board_disarmed(tmp_path_factory, first, moment, delay, second):
    """The drawn moments, and two kept as examples: SIGHUP while the rotors spin up (the run used to die
    at once, the board left to its watchdog), SIGTERM then SIGINT while the host waits for the phone."""
    tmp: Path = tmp_path_factory.mktemp("port")
    world_phone = f"udp://127.0.0.1:{_free_udp_port()}"
    # waiting for the phone: the host listens where the world does not send
    phone = f"udp://127.0.0.1:{_free_udp_port()}" if moment == "phone_wait" else world_phone
    with firmware_sim(tmp, "--world", "cubesat-1u", "--phone", world_phone) as sim:
        out = tmp / "runs"
        args = ("hil", "run", "--port", str(sim.link), "--phone", phone, "--phone-wait", "30")
        args += ("--duration", "60", "--no-plots", "--out", str(out))
        hil = _spawn(*args, log=tmp / "hil")
        try:
            if moment == "handshake":
                time.sleep(delay * 4)  # imports, then the handshake: ~1-2 s
            else:
                kind = "connected" if moment == "phone_wait" else moment
                _wait_until(
                    lambda: _run_dir(out) is not None and kind in _kinds(_run_dir(out)), 120.0, kind, hil
                )
                time.sleep(delay)
            hil.send_signal(first)
            if second is not None:
                time.sleep(second[1])
                if hil.poll() is None:
                    hil.send_signal(second[0])
            status = _ended(hil)
        finally:
            if hil.poll() is None:
                hil.kill()
                hil.wait()
        err = _text(tmp / "hil.err")
        run_dir = _run_dir(out)
        if run_dir is None:  # before the run started: nothing armed, nothing written
            assert status in (128 + first, -first), (status, err)
            assert "DISARMED -> ARMED" not in sim.log()
            return
        assert status == 1, f"status {status}: {err[-2000:]}"
        assert "Traceback" not in err, err
        summary = _honest_run_dir(run_dir)
        assert summary["exit"] in interrupted_by(first, second)
        disarms = _disarms(run_dir)
        assert len(disarms) <= 1 and all(reason == summary["exit"] for _, reason in disarms), disarms
        time.sleep(1.5)  # past the board's link timeout: a board left armed has failed safe by now
        if "DISARMED -> ARMED" in sim.log():  # the host armed it (whether or not it logged "armed")
            assert len(disarms) == 1, disarms
            if disarms[0][0] == "disarmed":  # not given up by a second interrupt during its wait
                _board_disarmed_by_the_host(sim)


def test_a_completed_port_run_leaves_the_board_disarmed(tmp_path):
    """A run that ends by itself disarms the board it armed (``disarmed``, reason ``run ended``): let go
    armed, the board spun its rotors at the last setpoint until its link watchdog tripped, and the next
    session found it in FAILSAFE, a link-lost fault in its telemetry that no run had suffered."""
    phone = f"udp://127.0.0.1:{_free_udp_port()}"
    with firmware_sim(tmp_path, "--world", "cubesat-1u", "--phone", phone) as sim:
        out = tmp_path / "runs"
        args = ("hil", "run", "--port", str(sim.link), "--phone", phone, "--duration", "6")
        hil = _spawn(*args, "--no-plots", "--out", str(out), log=tmp_path / "hil")
        status = _ended(hil)
        run_dir = _run_dir(out)
        assert status == 0 and run_dir is not None, _text(tmp_path / "hil.err")
        assert _honest_run_dir(run_dir)["exit"] == "completed"
        assert _disarms(run_dir) == [("disarmed", "run ended")]
        _board_disarmed_by_the_host(sim)
