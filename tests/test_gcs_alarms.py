"""The ground station's limits (hil/gcs/alarms.py): derived from the scenario and the board's configuration,
each named with a key the acknowledgement endpoint accepts, sent in the run's ``info``."""

from __future__ import annotations

import json

from firmware_sim.board.config import BatteryParams, BoardConfig, PowerThresholds
from hil.gcs import alarms
from hil.gcs import info as run_info
from hil.gcs.uplink import ALARM_KEY, parse_ack
from hil.runtime import faults as runtime_faults
from hil.runtime.phases import Phase
from hil.scenario import load_scenario


def test_the_board_thresholds_are_the_boards_own():
    """The host cannot import the board: its copy of the thresholds must agree with the board's."""
    th = PowerThresholds()
    assert alarms.WARN_V_CELL == th.warn_v_cell and alarms.SHED_V_CELL == th.shed_v_cell
    assert alarms.BROWNOUT_V == th.brownout_v and alarms.BROWNOUT_RELEASE_V == th.brownout_release_v
    assert alarms.DEFAULT_CELLS == BatteryParams().cells
    assert alarms.DEFAULT_LINK_TIMEOUT_S == BoardConfig().link_timeout_s


def test_limits_come_from_the_scenario():
    sc = load_scenario("cubesat-1u")
    by_key = {a["key"]: a for a in alarms.alarm_limits(sc)}
    assert by_key["point_err_deg:high"]["value"] == sc.settle_deg
    lim = sc.spacecraft.limits
    for k in range(sc.spacecraft.n_units):
        assert by_key[f"gimbal_rate_{k}:high"]["value"] == lim.max_gimbal_rate
        assert by_key[f"gimbal_rate_{k}:high"]["op"] == "abs_above"
        low = by_key[f"rotor_speed_{k}:low"]
        assert (low["value"], low["op"]) == (lim.min_rotor_speed, "below")
        # the slew and the hold only: not the warm-up (spin-up) nor an operator's suspension (rotors stopping)
        assert low["phases"] == [int(Phase.SLEW), int(Phase.HOLD)]
        assert by_key[f"rotor_speed_{k}:high"]["value"] == lim.max_rotor_speed
        assert by_key[f"rotor_speed_{k}:high"]["phases"] == sorted(int(p) for p in Phase)
    assert by_key["link_age_ms:high"]["value"] == 1e3 * sc.board_options["link_timeout"]
    assert by_key["tel_age_ms:high"]["value"] == 1e3 * runtime_faults.STALE_AFTER_S
    assert by_key["battery_v:low"]["value"] == 3 * alarms.WARN_V_CELL
    assert by_key["ubec_v:brownout"]["value"] == alarms.BROWNOUT_V
    assert by_key["ubec_v:brownout"]["severity"] == "critical"
    # a scenario's own board: two cells and a 1 s link watchdog
    two = sc.with_changes(board_options={**sc.board_options, "cells": 2, "link_timeout": 1.0}, settle_deg=2.0)
    by_key = {a["key"]: a for a in alarms.alarm_limits(two)}
    assert by_key["battery_v:shed"]["value"] == round(2 * alarms.SHED_V_CELL, 3)
    assert by_key["link_age_ms:high"]["value"] == 1000.0
    assert by_key["point_err_deg:high"]["value"] == 2.0


def test_every_key_is_one_the_acknowledgement_accepts_and_clears_inside_its_limit():
    sc = load_scenario("cubesat-1u")
    for a in alarms.alarm_limits(sc):
        assert ALARM_KEY.fullmatch(a["key"]), a["key"]
        assert parse_ack(json.dumps({"alarm": a["key"], "raised_t": 1.5}).encode())["alarm"] == a["key"]
        if a["op"] == "below":
            assert a["clear"] > a["value"]
        elif a["op"] in ("above", "abs_above"):
            assert 0 < a["clear"] < a["value"]


def test_the_runs_info_carries_the_limits():
    sc = load_scenario("cubesat-1u")
    info = run_info.info(mode="live", run="r", columns=["t"], uplink=True, scenario=sc)
    assert info["alarms"] == alarms.alarm_limits(sc)
    bare = run_info.info(mode="replay", run="r", columns=["t"], uplink=False, scenario=None)
    assert bare["alarms"] == []
