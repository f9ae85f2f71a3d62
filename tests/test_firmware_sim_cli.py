"""``firmware-sim``: the console command through a real subprocess and a real pty, and its option parsing."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from conformance.host import SerialHost, heartbeat

from firmware_sim.cli import build_parser, main, make_board, parse_dead_esc, parse_sag, parse_stall
from hil.timing.clock import LockstepClock
from protocol.errors import ConfigError
from protocol.messages import BoardState, ResetCause, Telemetry


def spawn(*args: str) -> tuple[subprocess.Popen[str], str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    path = proc.stdout.readline().strip()
    assert path.startswith("/dev/"), (path, proc.stderr.read() if proc.poll() is not None else "")
    return proc, path


def test_help_teaches_by_example(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for example in (
        "--link /tmp/vscmg-board",
        "--corrupt 0.01",
        "--hang-at 5",
        "--sag 6@10/5",
        "--dead-esc 1@3",
    ):
        assert example in out


@pytest.mark.parametrize(
    ("argv", "where"),
    [
        (["--units", "9"], "--units: 9 is outside 1..8"),
        (["--frame-rate", "1000"], "--frame-rate: 1000.0 is outside"),
        (["--sag", "3x"], "--sag"),
        (["--stall", "5"], "--stall"),
        (["--dead-esc", "99"], "--dead-esc"),
        (["--corrupt", "1.5"], "--corrupt: 1.5 is not a probability"),
        (["--soc", "2"], "--soc: 2.0 is outside 0..1"),
        (
            ["--avr", "--world", "cubesat-1u", "--unplug", "3:1"],
            "unplug: not available with the firmware board",
        ),
        # the world sets the units: a different --units was silently replaced by the scenario's
        (["--world", "cubesat-1u", "--units", "3"], "the world cubesat-1u has 4 units"),
    ],
)
def test_bad_options_are_clear_errors(argv, where, capsys):
    assert main(argv + ["--duration", "0.01"]) == 2
    err = capsys.readouterr().err
    assert "firmware-sim: error:" in err and where in err


@pytest.mark.parametrize("duration", ["0", "-0.0", "-5", "nan", "inf", "1e999"])
def test_a_duration_that_is_not_a_finite_positive_time_is_refused(duration, capsys):
    """``--duration 0`` or below served nothing and said it stopped; ``nan`` and ``inf`` served forever."""
    with pytest.raises(SystemExit) as exc:
        main(["--duration", duration])
    assert exc.value.code == 2
    assert "--duration: must be a finite number of seconds > 0" in capsys.readouterr().err


def test_the_worlds_own_units_may_be_given_again():
    assert main(["--world", "cubesat-1u", "--units", "4", "--duration", "0.01"]) == 0


def test_fault_specs_parse():
    assert parse_sag("6@10/5") == (6.0, 10.0, 5.0)
    assert parse_sag("2.5") == (2.5, None, 0.0)
    assert parse_stall("5:2") == (5.0, 2.0)
    assert parse_dead_esc("3@1.5") == (3, 1.5)
    assert parse_dead_esc("0") == (0, None)
    with pytest.raises(ConfigError, match="--sag-ohms"):
        parse_sag("@3", "--sag-ohms")


def test_options_schedule_faults_on_the_board():
    args = build_parser().parse_args(
        [
            "--units",
            "3",
            "--corrupt",
            "0.01",
            "--drop",
            "0.002",
            "--stall",
            "4:1",
            "--hang-at",
            "5",
            "--sag",
            "6@10/5",
            "--sag-ohms",
            "0.5@2",
            "--brownout-at",
            "8",
            "--dead-esc",
            "1@3",
            "--seed",
            "4",
        ]
    )
    board = make_board(args, LockstepClock())
    f = board.faults
    assert board.config.n_units == 3 and board.config.seed == 4
    assert (f.noise.corrupt, f.noise.drop) == (0.01, 0.002)
    assert [(s.start, s.duration) for s in f.stalls] == [(4.0, 1.0)]
    assert f.hangs == [5.0]
    assert f.battery_sag(12.5) == (pytest.approx(6 * 0.5 + 0.0), pytest.approx(0.5))
    assert f.battery_sag(8.1)[0] == pytest.approx(3 * 4.2)
    assert not f.channel_dead(1, 2.9) and f.channel_dead(1, 3.0)


def test_command_serves_a_pty_behind_a_symlink_and_stops_on_sigterm(tmp_path):
    link = tmp_path / "vscmg-board"
    proc, path = spawn("--link", str(link), "--units", "2", "--telemetry-rate", "50")
    try:
        assert os.path.realpath(link) == path
        host = SerialHost(str(link))
        reply = host.handshake()
        assert reply.n_units == 2 and reply.state == BoardState.DISARMED
        host.keepalive = heartbeat
        assert host.wait_type(Telemetry, 1.0).state == BoardState.DISARMED
        host.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0
        assert not link.exists() and not link.is_symlink()
        assert "stopped" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_command_injects_a_hang_from_the_command_line():
    proc, path = spawn("--hang-at", "0.3", "--mcu-watchdog", "0.2", "--duration", "10")
    try:
        time.sleep(0.8)  # hang at 0.3 s, reset at 0.5 s, booted by 0.55 s
        host = SerialHost(path)
        assert host.handshake().reset_cause == ResetCause.WATCHDOG
        host.close()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=5) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_duration_ends_the_command_by_itself_on_the_wall_clock():
    started = time.monotonic()
    proc, path = spawn("--duration", "0.3")
    assert proc.wait(timeout=5) == 0
    assert time.monotonic() - started >= 0.3  # real time by default: never faster than the wall clock
    assert "stopped" in proc.stderr.read()


def test_a_link_that_cannot_be_made_is_a_clear_error(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--link", str(tmp_path / "no-such-dir" / "board")],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.startswith("firmware-sim: error: cannot make the link")
    assert "Traceback" not in done.stderr


def test_the_command_says_when_a_host_connects_and_arms_and_explains_what_it_dropped():
    from protocol.messages import Ack, Arm

    proc, path = spawn("--units", "2", "--telemetry-rate", "1000")
    try:
        time.sleep(3.0)  # ~150 KB of telemetry with nobody reading: more than the pty holds, dropped (on a
        # loaded machine the board makes less of it in that time)
        host = SerialHost(path)
        host.handshake()
        host.keepalive = heartbeat
        assert isinstance(host.request(Arm()), Ack)
        armed_until = time.monotonic() + 0.6  # heartbeats keep it ARMED; the status thread looks every 0.1 s
        while time.monotonic() < armed_until:
            host.wait_type(Telemetry, 1.0)
        host.close()
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0
        err = proc.stderr.read()
        assert "waiting for a host" in err and "host connected" in err
        assert "-> ARMED" in err, err  # from DISARMED, or BOOT if handshake and Arm fall between two looks
        assert "bytes of the board's output were dropped" in err and "no host" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
