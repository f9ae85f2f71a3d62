"""A brown-out release level the UBEC rail can never reach from a full pack.

What a hunt found: ``BoardConfig.validate`` held ``brownout_release_v`` under the UBEC's set voltage only.
But the rail is also the battery less the regulator's dropout: a 2-cell pack (8.4 V full) behind a 12 V
UBEC gives 7.9 V at most, so a release level of 9 V was accepted and the board never left reset — a
handshake timeout, not an error (as ``cells = 1`` once was). The release level must lie below what a full
pack can put on the rail; the validation now says so, naming the field.
"""

from __future__ import annotations

import hypothesis.strategies as st
import pytest
from conformance.host import lockstep
from hypothesis import example, given, settings

from firmware_sim.board.config import (
    LIPO_OCV_CURVE,
    BatteryParams,
    BoardConfig,
    PowerConfig,
    PowerThresholds,
    UbecParams,
)
from protocol.errors import ConfigError
from protocol.messages import HelloReply

FULL_CELL_V = LIPO_OCV_CURVE[-1][1]


@settings(max_examples=40, deadline=None)
@given(
    cells=st.integers(2, 4),
    set_voltage_v=st.sampled_from([5.0, 6.0, 7.4, 8.0, 12.0]),
    dropout_v=st.sampled_from([0.0, 0.5, 1.0, 2.0]),
    release_v=st.floats(4.5, 12.0),
)
@example(cells=2, set_voltage_v=12.0, dropout_v=0.5, release_v=9.0)
@example(cells=2, set_voltage_v=8.0, dropout_v=0.5, release_v=7.95)
def test_a_board_either_boots_from_a_full_pack_or_its_config_is_refused(
    cells, set_voltage_v, dropout_v, release_v
):
    cfg = BoardConfig(
        n_units=2,
        power=PowerConfig(
            battery=BatteryParams(cells=cells),
            ubec=UbecParams(set_voltage_v=set_voltage_v, dropout_v=dropout_v),
            thresholds=PowerThresholds(brownout_v=release_v - 0.2, brownout_release_v=release_v),
        ),
    )
    rail_ceiling_v = min(set_voltage_v, cells * FULL_CELL_V - dropout_v)
    try:
        cfg.validate()
    except ConfigError as refused:
        assert refused.where.startswith("BoardConfig.power."), refused
        assert release_v > rail_ceiling_v - 0.05, (refused, rail_ceiling_v)  # only what cannot boot
        return
    board, clock, host = lockstep(cfg)
    assert isinstance(host.handshake(timeout=0.1, tries=5), HelloReply)


def test_the_refusal_names_the_release_level_and_the_rail_it_cannot_reach():
    thresholds = PowerThresholds(brownout_v=8.8, brownout_release_v=9.0)
    with pytest.raises(ConfigError) as caught:
        BoardConfig(
            power=PowerConfig(
                battery=BatteryParams(cells=2), ubec=UbecParams(set_voltage_v=12.0), thresholds=thresholds
            )
        ).validate()
    assert caught.value.where == "BoardConfig.power.thresholds.brownout_release_v"
    assert "7.9" in str(caught.value)
