"""The ground station's limits (hil/gcs/alarms.py) at thresholds beside the defaults: a scenario's
``min_rotor_speed = 0`` (allowed: ``ActuatorLimits``) made the rotor-speed alarm's clear level
``0 * (1 + HYSTERESIS) = 0``, no band at all — a rotor hovering at its limit raised and cleared the alarm
row after row — and a threshold below zero had its band on the wrong side (outside the limit). Every limit
with a threshold now clears strictly inside it, by :data:`~hil.gcs.alarms.HYSTERESIS` of its size (of the
rotor's speed range for a zero minimum)."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.gcs import alarms
from hil.scenario import load_scenario

BASE = load_scenario("cubesat-1u")
LIMITS = BASE.spacecraft.limits
NOMINAL = BASE.spacecraft.nominal_rotor_speed / LIMITS.max_rotor_speed  # a minimum must stay below it


@settings(max_examples=60, deadline=None)
@given(
    min_fraction=st.one_of(st.just(0.0), st.floats(0.0, 0.99 * NOMINAL)),
    settle_deg=st.floats(1e-3, 180.0),
)
def test_every_limit_clears_strictly_inside_its_threshold(min_fraction, settle_deg):
    limits = replace(LIMITS, min_rotor_speed=min_fraction * LIMITS.max_rotor_speed)
    sc = BASE.with_changes(spacecraft=replace(BASE.spacecraft, limits=limits), settle_deg=settle_deg)
    for a in alarms.alarm_limits(sc):
        if a["op"] == "below":
            assert a["clear"] > a["value"], a
        elif a["op"] in ("above", "abs_above"):
            assert a["clear"] < a["value"], a
    low = {a["key"]: a for a in alarms.alarm_limits(sc)}["rotor_speed_0:low"]
    band = alarms.HYSTERESIS * (low["value"] or LIMITS.max_rotor_speed)  # a zero minimum: of the range
    assert low["clear"] - low["value"] >= band * (1 - 1e-12), low
