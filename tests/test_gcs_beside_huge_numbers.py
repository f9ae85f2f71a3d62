"""A JSON integer of any size in a command or an acknowledgement, through the real tornado server.

JSON's integers have no bound and ``json.loads`` gives a Python int of up to 4300 digits; ``math.isfinite``
of one beyond a float's range (10**400 as a slew's angle, or an alarm's ``raised_t``) raised OverflowError
in ``hil.gcs.uplink``, which the server answered 500 (``reason: error``). Each must be a 400 (``format``)
saying which field, logged as ``rejected`` like any malformed body. The strategies draw the integer as its
JSON text, from one digit to past the body's cap (``MAX_BODY``: then 413), so every size is covered, not
only the ±400 the older properties draw.
"""

from __future__ import annotations

import time
from typing import Any

from gcs_support import UplinkLog, request
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation
from hil.gcs.uplink import ANGLE_RANGE, MAX_BODY

# An integer as JSON writes it: an optional minus, no leading zero, any number of digits.
json_integers = st.from_regex(r"-?(0|[1-9][0-9]{0,5000})", fullmatch=True)
SETTINGS = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _a_float(literal: str) -> bool:
    """Whether the JSON integer ``literal`` is within a float's range (±1.8e308)."""
    try:
        float(int(literal))
    except OverflowError:
        return False
    return True


def _post(station: GroundStation, path: str, body: bytes) -> tuple[int, Any]:
    return request(station, "POST", path, body, headers={"Content-Type": "application/json"})


def _check(
    station: GroundStation, log: UplinkLog, path: str, body: bytes, accepted: bool, field: str
) -> None:
    """``body`` POSTed to ``path``: 413 past the cap, else 202 when ``accepted``, else 400 ``format``
    naming ``field`` and one ``rejected`` record; never a 500."""
    status, answer = _post(station, path, body)
    before = len(log.records)
    assert station.uplink is not None
    station.uplink.service(log, time.monotonic())  # the control tick: logs the refusal, empties the inbox
    rejected = [r for r in log.records[before:] if r.get("status") == "rejected"]
    if len(body) > MAX_BODY:
        assert (status, answer["reason"]) == (413, "size"), answer
    elif accepted:
        assert status == 202 and not rejected, answer
    else:
        assert (status, answer["reason"]) == (400, "format"), answer
        assert field in answer["error"] and len(answer["error"]) < 300
        assert len(rejected) == 1 and rejected[0]["reason"] == "format"
    assert "error" not in station.server.counters()["rejected"]


def test_a_slew_angle_of_any_json_integer_is_answered_400_past_its_range_never_500():
    with GroundStation.live(bind="127.0.0.1:0") as station:
        assert station.uplink is not None
        station.uplink.open()  # what the run's start does (LiveFeed.started): no run, no command taken
        log = UplinkLog()

        @SETTINGS
        @given(json_integers, st.sampled_from(sorted(ANGLE_RANGE)))
        @example("1" + "0" * 400, "roll_deg")  # the reviewer's
        @example("-" + "9" * 309, "yaw_deg")  # just past a float's range
        @example("9" * 4000, "pitch_deg")  # near the cap, still under it
        def one(literal: str, key: str) -> None:
            angles = dict.fromkeys(ANGLE_RANGE, "0")
            angles[key] = literal
            fields = ", ".join(f'"{k}": {v}' for k, v in angles.items())
            body = ('{"command": "slew", ' + fields + "}").encode()
            _check(station, log, "/api/command", body, abs(int(literal)) <= ANGLE_RANGE[key], key)

        one()


def test_an_alarm_time_of_any_json_integer_is_answered_400_past_a_floats_range_never_500():
    with GroundStation.live(bind="127.0.0.1:0") as station:
        assert station.uplink is not None
        station.uplink.open()  # what the run's start does (LiveFeed.started): no run, no command taken
        log = UplinkLog()

        @SETTINGS
        @given(json_integers)
        @example("1" + "0" * 400)  # the reviewer's
        @example("1" + "0" * 308)  # 1e308: a float, accepted
        @example("-" + "9" * 309)
        def one(literal: str) -> None:
            body = ('{"alarm": "point_err_deg:high", "raised_t": ' + literal + "}").encode()
            _check(station, log, "/api/ack", body, _a_float(literal), "raised_t")

        one()
