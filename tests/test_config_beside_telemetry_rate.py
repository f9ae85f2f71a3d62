"""A scenario's ``[board] telemetry_rate`` slow enough that the host can never see the board live: at 0.1 Hz
(firmware-sim takes it) every frame is older than the host's stale bound (0.25 s) long before the next, and
the run loses the board it drives. Refused as the file is read, naming the key and the bound, as a control
period longer than the link timeout is."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.scenario import parse_scenario
from protocol.errors import ConfigError


def _scenario(rate: float) -> str:
    return f"[scenario]\nname = 'x'\nduration_s = 3\n[board]\ntelemetry_rate = {rate!r}\n"


@given(st.floats(min_value=0.1, max_value=8.0, exclude_max=True))
def test_a_telemetry_rate_under_two_frames_per_stale_bound_is_refused(rate):
    with pytest.raises(ConfigError) as caught:
        parse_scenario(_scenario(rate), Path("slow.toml"))
    assert caught.value.where == "slow.toml: board.telemetry_rate"
    assert "stale once its telemetry is 0.25 s old" in caught.value.detail
    assert "at least 8 Hz" in caught.value.detail


@given(st.floats(min_value=8.0, max_value=1000.0))
def test_two_frames_per_stale_bound_or_more_is_taken(rate):
    scenario = parse_scenario(_scenario(rate), Path("ok.toml"))
    assert scenario.board_options["telemetry_rate"] == rate


def test_the_bound_is_the_runtime_s():
    """The reader is below the runtime (import-linter's layers): its copy of the stale bound is held equal
    here, and the default rate to firmware-sim's."""
    from firmware_sim.board.config import BoardConfig
    from hil.runtime.faults import STALE_AFTER_S
    from hil.scenario import reader

    assert reader.HOST_STALE_AFTER_S == STALE_AFTER_S
    assert reader.MIN_TELEMETRY_RATE_HZ == 2 / STALE_AFTER_S
    assert reader.DEFAULT_TELEMETRY_RATE_HZ == BoardConfig().telemetry_rate_hz


def test_firmware_sim_refuses_the_world_at_start(tmp_path, capsys):
    from firmware_sim.cli import main

    world = tmp_path / "slow.toml"
    world.write_text(_scenario(0.1))
    assert main(["--world", str(world), "--duration", "0.01"]) == 2
    assert "slow.toml: board.telemetry_rate: 0.1 Hz" in capsys.readouterr().err
