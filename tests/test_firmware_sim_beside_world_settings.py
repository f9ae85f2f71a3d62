"""``firmware-sim --world SCENARIO`` beside the scenario's ``[board]`` and ``[faults]``: the world set only
the unit count, so a scenario's ``hang_at = 2.0`` never hung the board and its ``link_timeout = 1.0`` was
served as the 0.25 s default (a 2 Hz controller the reader accepts for it had the board fail safe between
commands). The scenario's settings are now the board's; an option the command line (or a
``spawn://firmware-sim?world=`` URL) gives beside them overrides a single-valued one, said on stderr naming
both, and the repeatable faults add up, each scheduled once."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from firmware_sim.cli import build_parser, make_board, world_options
from hil.link.transports import create_transport
from hil.scenario import load_scenario
from hil.timing.clock import LockstepClock

ROOT = Path(__file__).resolve().parents[1]


def _world(tmp_path: Path, board: str = "", faults: str = "") -> Path:
    """cubesat-1u with ``board`` lines added to its ``[board]`` and ``faults`` to its ``[faults]``."""
    text = (ROOT / "fixtures" / "scenarios" / "cubesat-1u.toml").read_text()
    text = text.replace("link_timeout = 0.25\n", board or "link_timeout = 0.25\n")
    text = text.replace("[faults]\n", "[faults]\n" + faults)
    path = tmp_path / "world.toml"
    path.write_text(text)
    return path


def _board(path: Path, *argv: str):  # type: ignore[no-untyped-def]
    """The board ``firmware-sim --world path *argv`` serves (its options as main() settles them)."""
    line = ["--world", str(path), *argv]
    args = build_parser().parse_args(line)
    scenario = load_scenario(str(path))
    args.units = scenario.n_units
    notes = world_options(args, line, scenario)
    return make_board(args, LockstepClock()), notes


def test_the_worlds_board_and_faults_are_the_boards(tmp_path):
    path = _world(tmp_path, "link_timeout = 1.0\nmcu_watchdog = 0.8\n", "hang_at = [2.0]\nstall = ['5:1']\n")
    board, notes = _board(path)
    assert notes == []
    assert (board.config.link_timeout_s, board.config.mcu_watchdog_s) == (1.0, 0.8)
    assert board.config.telemetry_rate_hz == 50.0  # the scenario's, not firmware-sim's default of 20
    assert board.faults.hangs == [2.0]
    assert [(s.start, s.duration) for s in board.faults.stalls] == [(5.0, 1.0)]


def test_an_option_beside_the_world_overrides_it_and_says_so_naming_both(tmp_path):
    path = _world(tmp_path, "link_timeout = 1.0\n")
    board, notes = _board(path, "--link-timeout", "0.5", "--telemetry-rate", "50")
    assert board.config.link_timeout_s == 0.5
    assert notes == [f"--link-timeout 0.5 overrides the world's board.link_timeout = 1.0 ({path})"]


def test_repeatable_faults_add_up_each_scheduled_once(tmp_path):
    path = _world(tmp_path, faults="hang_at = [2.0]\n")
    board, notes = _board(path, "--hang-at", "2", "--hang-at", "3")
    assert notes == [] and sorted(board.faults.hangs) == [2.0, 3.0]


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_worlds_hang_resets_the_board_of_the_real_command(tmp_path):
    path = _world(tmp_path, faults="hang_at = [1.0]\n")
    phone = f"udp://127.0.0.1:{_free_udp_port()}"
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--world", str(path), "--phone", phone, "--duration", "3"],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "board reset at" in done.stderr and "WATCHDOG" in done.stderr
    assert "; 1 reset(s)" in done.stderr


def test_the_real_command_says_an_override(tmp_path):
    path = _world(tmp_path, "link_timeout = 1.0\n")
    phone = f"udp://127.0.0.1:{_free_udp_port()}"
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--world", str(path), "--phone", phone, "--link-timeout",
         "0.5", "--duration", "0.5"],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "firmware-sim: --link-timeout 0.5 overrides the world's board.link_timeout = 1.0" in done.stderr


def test_a_spawned_world_runs_its_scenarios_faults(tmp_path):
    path = _world(tmp_path, faults="hang_at = [1.0]\n")
    phone = f"udp://127.0.0.1:{_free_udp_port()}"
    transport = create_transport(f"spawn://firmware-sim?world={path}&phone={phone}&start_timeout=120")
    transport.open()
    try:
        deadline = time.monotonic() + 60
        while "WATCHDOG" not in transport.stderr_text():  # type: ignore[attr-defined]
            assert time.monotonic() < deadline, transport.stderr_text()  # type: ignore[attr-defined]
            transport.read(0.2)
    finally:
        transport.close()


@pytest.mark.parametrize("units", ["3"])
def test_the_units_beside_a_world_are_still_refused(tmp_path, units, capsys):
    from firmware_sim.cli import main

    assert main(["--world", str(_world(tmp_path)), "--units", units, "--duration", "0.01"]) == 2
    assert "has 4 units" in capsys.readouterr().err
