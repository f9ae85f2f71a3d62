"""The real firmware in the closed loop: the ATmega2560 binary under simavr (``emu://?board=firmware``,
:class:`firmware_sim.avr.stepped.FirmwareBoard`) drives the world in lockstep, deterministically, and
compares with the Python board within the bounds docs/firmware_sim.md explains."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_sim.avr.stepped import FirmwareBoard
from hil.link.transports import create_transport
from hil.runtime.loop import RunOptions, RunResult, run
from hil.scenario import load_scenario
from hil.timing.clock import LockstepClock
from protocol.errors import ConfigError, LinkError, TransportError
from protocol.messages import BoardState

SCENARIO = "cubesat-1u"
SCENARIOS = ("cubesat-1u", "paper-testbed")
"""Every scenario the project ships (fixtures/scenarios): each settles through the firmware too."""


@pytest.fixture(scope="module", params=SCENARIOS)
def side_by_side(request: pytest.FixtureRequest) -> dict[str, RunResult]:
    """A scenario through each board, same seed, in lockstep (no run directory)."""
    scenario = load_scenario(request.param)
    return {
        board: run(scenario.with_board(board), RunOptions(out_root=None))
        for board in ("emulator", "firmware")
    }


@pytest.mark.firmware
def test_firmware_lockstep_run_settles(side_by_side: dict[str, RunResult]) -> None:
    summary = side_by_side["firmware"].summary
    assert summary["exit"] == "completed"
    assert summary["settled"], summary["final_error_deg"]
    assert summary["final_error_deg"] < summary["settle_requirement_deg"]
    assert summary["board_resets"] == 0 and summary["failsafe_events"] == 0


@pytest.mark.firmware
def test_firmware_lockstep_is_deterministic() -> None:
    """Same seed, same trajectory: two short runs through the firmware give identical traces."""
    scenario = load_scenario(SCENARIO).with_board("firmware")
    traces = [run(scenario, RunOptions(out_root=None, duration_s=1.0)).trace.arrays() for _ in range(2)]
    assert traces[0].keys() == traces[1].keys()
    for key in traces[0]:
        assert np.array_equal(traces[0][key], traces[1][key], equal_nan=True), key


@pytest.mark.firmware
def test_boards_side_by_side_within_bounds(side_by_side: dict[str, RunResult]) -> None:
    """The bounds of docs/firmware_sim.md ("The two boards side by side")."""
    python, firmware = (side_by_side[b] for b in ("emulator", "firmware"))
    a, b = python.trace.arrays(), firmware.trace.arrays()
    n = min(len(a["t"]), len(b["t"]))
    assert n > 1000 and np.allclose(a["t"][:n], b["t"][:n])  # the same schedule of control ticks
    assert np.nanmax(np.abs(a["gimbal_rate"][:n] - b["gimbal_rate"][:n])) < 0.003  # rad/s
    assert np.nanmax(np.abs(a["delta"][:n] - b["delta"][:n])) < 0.007  # singularity measure
    assert np.nanmax(np.abs(a["point_err_deg"][:n] - b["point_err_deg"][:n])) < 0.35
    ps, fs = python.summary, firmware.summary
    assert abs(fs["settle_s"] - ps["settle_s"]) < 1.0
    assert abs(fs["slew_s"] - ps["slew_s"]) < 0.1  # the slew starts at the same time: same spin-up
    assert fs["peak_gimbal_rate"] <= ps["peak_gimbal_rate"] * 1.2
    kinds = {board: {e["kind"] for e in r.events} for board, r in side_by_side.items()}
    assert kinds["emulator"] == kinds["firmware"]


@pytest.mark.firmware
def test_firmware_board_steps_the_binary_with_the_worlds_battery() -> None:
    """Stepped on a lockstep clock the firmware boots, puts out frames at its rate on the timers' tick
    grid, and its ADC reads the battery firmware_sim's model solves; a sag of that battery browns the
    MCU out (the harness's detector on the rail the model gives)."""
    clock = LockstepClock()
    with FirmwareBoard(clock=clock) as board:
        while clock.now() < 1.0:
            clock.set(min(board.next_deadline(), clock.now() + 0.01))
            board.step()
        frames = list(board.timeline.frames)
        assert 45 <= len(frames) <= 50  # 50 Hz from boot
        assert all(w is not None and (w * 2) % 1 == 0 for w in frames[-1].widths)  # whole 0.5 µs ticks
        assert board.state is BoardState.BOOT  # no host yet
        assert board.power.battery_v == pytest.approx(12.6, abs=0.1)
        board.faults.sag(drop_v=12.6, at=1.2, duration=0.3)  # the pack collapses: brown-out
        while clock.now() < 2.5:
            clock.set(min(board.next_deadline(), clock.now() + 0.01))
            board.step()
        causes = [r.cause.name for r in board.resets]
        assert causes == ["POWER_ON", "BROWN_OUT"]
        assert 1.5 <= board.resets[-1].t <= 1.6  # released once the rail is back
        assert board.timeline.frames[-1].t > 2.4  # pulses again after the reset


def test_emu_board_option_names_the_boards() -> None:
    with pytest.raises(TransportError, match="board='fpga' is not one of emulator, firmware"):
        create_transport("emu://?units=4&board=fpga")


@pytest.mark.firmware
def test_firmware_board_refuses_an_unplug() -> None:
    link = create_transport("emu://?units=4&board=firmware&unplug=3:1")
    with pytest.raises(ConfigError, match="unplug"):
        _ = link.board  # type: ignore[attr-defined]


@pytest.mark.firmware
def test_firmware_board_feeds_a_long_write_whole() -> None:
    """A host write longer than one harness command line carries (a server reads up to 64 KiB at once)
    reaches UART0 whole, in several ``rx`` commands; an over-long command line is refused, not cut short
    (which lost the write's tail silently)."""
    with FirmwareBoard(clock=LockstepClock()) as board:
        board.feed(bytes(range(1, 256)) * 4)  # 1020 bytes
        assert board.harness.command("stats")[0] == "1020"
        with pytest.raises(LinkError, match="longer than 511 characters"):
            board.harness.command("rx " + "01" * 300)
        assert board.harness.command("stats")[0] == "1020"
