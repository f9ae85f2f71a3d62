"""Multi-rate merge: hold-last-sample steps at the driving sensor's rate, every policy, batch == live."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.estimator import VariationalEstimator
from hil.estimation.multirate import MergePolicy, Merger, merge
from hil.estimation.params import EstimatorParams
from hil.estimation.sensors import KINDS, MergedSteps, SensorKind, SensorSample, SensorStream, StepFlag
from protocol.errors import ConfigError

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG


def stream(kind: SensorKind, t, value=None) -> SensorStream:
    t = np.asarray(t, dtype=float)
    xyz = np.column_stack(
        [np.arange(len(t), dtype=float) + 100 * int(kind), np.zeros(len(t)), np.ones(len(t))]
    )
    if value is not None:
        xyz = np.broadcast_to(np.asarray(value, float), (len(t), 3)).copy()
    return SensorStream(kind, t, xyz)


def live(streams: dict, policy: MergePolicy, order: list[SensorSample] | None = None):
    """Feed a live merger given the batch merge's roles, in ``order`` (default: time order, at equal
    times the driver's sample last, as it completes the step); returns its steps and counters."""
    roles = merge(streams, policy)[1]
    driver = roles.driver
    merger = Merger(
        MergePolicy(**{**policy.__dict__, "driver": driver, "failover_order": roles.failover_order})
    )
    if order is None:
        order = sorted(
            (x for s in streams.values() for x in s.samples()), key=lambda x: (x.t_s, x.kind == driver)
        )
    steps = [st_ for x in order for st_ in merger.push(x)] + merger.flush()
    return MergedSteps.from_steps(steps), merger.stats


def assert_same(a: MergedSteps, b: MergedSteps) -> None:
    for name in ("t", "gyr", "acc", "mag", "age", "fresh", "flags"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_steps_at_the_fastest_sensor_holding_the_others_with_their_age():
    streams = {
        GYR: stream(GYR, [0.0, 0.01, 0.02, 0.03, 0.04]),
        ACC: stream(ACC, [0.0, 0.02, 0.04]),
        MAG: stream(MAG, [0.005, 0.025]),
    }
    steps, stats = merge(streams)
    assert stats.driver == GYR and len(steps) == 5
    np.testing.assert_array_equal(steps.t, [0.0, 0.01, 0.02, 0.03, 0.04])
    np.testing.assert_array_equal(steps.acc[:, 0], [100, 100, 101, 101, 102])  # held
    np.testing.assert_allclose(steps.age[:, ACC], [0, 0.01, 0, 0.01, 0], atol=1e-15)
    # the magnetometer has not spoken at t = 0: stale there, held afterwards
    assert np.isnan(steps.mag[0]).all() and steps.flags[0] & StepFlag.MAG_STALE
    np.testing.assert_array_equal(steps.mag[1:, 0], [200, 200, 201, 201])
    np.testing.assert_allclose(steps.age[1:, MAG], [0.005, 0.015, 0.005, 0.015], atol=1e-15)
    assert steps.age[0, MAG] == math.inf
    np.testing.assert_array_equal(steps.fresh[:, ACC], [True, False, True, False, True])
    np.testing.assert_allclose(steps.h, [0, 0.01, 0.01, 0.01, 0.01], atol=1e-15)
    assert stats.stale_steps == {"gyr": 0, "acc": 0, "mag": 1}


def test_driver_is_the_fastest_stream_with_ties_going_to_the_gyroscope():
    t = np.arange(0, 1, 0.005)
    fast_acc = {GYR: stream(GYR, t[::2]), ACC: stream(ACC, t), MAG: stream(MAG, t[::4])}
    assert merge(fast_acc)[1].driver == ACC
    assert merge(fast_acc)[1].failover_order == (GYR, MAG)
    tie = {GYR: stream(GYR, t), ACC: stream(ACC, t + 0.001), MAG: stream(MAG, t[::4])}
    assert merge(tie)[1].driver == GYR
    assert merge(fast_acc, MergePolicy(driver=MAG))[1].driver == MAG


def test_jittered_timestamps_step_at_the_actual_times_deterministically():
    rng = np.random.default_rng(1)
    t = np.cumsum(0.005 + rng.uniform(-0.001, 0.001, 400))
    streams = {GYR: stream(GYR, t), ACC: stream(ACC, t + 0.0007), MAG: stream(MAG, t[::4] + 0.002)}
    a, _ = merge(streams)
    b, _ = merge(streams)
    assert_same(a, b)
    np.testing.assert_array_equal(a.t, t)
    assert np.ptp(a.h[1:]) > 0.001  # h follows the jitter


def test_duplicated_timestamps_first_wins_and_are_counted():
    streams = {
        GYR: stream(GYR, [0.0, 0.01, 0.01, 0.02]),
        ACC: stream(ACC, [0.0, 0.0, 0.02]),
        MAG: stream(MAG, [0.0]),
    }
    steps, stats = merge(streams)
    np.testing.assert_array_equal(steps.t, [0.0, 0.01, 0.02])
    np.testing.assert_array_equal(steps.gyr[:, 0], [0, 1, 3])  # row 2 (the duplicate) dropped
    np.testing.assert_array_equal(steps.acc[:, 0], [100, 100, 102])
    assert stats.duplicate == {"gyr": 1, "acc": 1, "mag": 0}


def test_out_of_order_samples_are_dropped_and_counted():
    streams = {
        GYR: stream(GYR, [0.0, 0.02, 0.01, 0.03]),
        ACC: stream(ACC, [0.0, 0.015, 0.005, 0.03]),
        MAG: None,
    }
    steps, stats = merge({k: v for k, v in streams.items() if v is not None})
    np.testing.assert_array_equal(steps.t, [0.0, 0.02, 0.03])
    np.testing.assert_array_equal(steps.acc[:, 0], [100, 101, 103])
    assert stats.out_of_order == {"gyr": 1, "acc": 1, "mag": 0}
    assert stats.stale_steps["mag"] == 3  # a sensor that never speaks is stale everywhere


def test_nan_samples_are_dropped_counted_logged_and_the_sensor_goes_stale(caplog):
    t = np.arange(0, 1.0, 0.01)
    mag = stream(MAG, t[::2])
    mag.xyz[10:] = np.nan  # the magnetometer sends NaN from 0.2 s on
    streams = {GYR: stream(GYR, t), ACC: stream(ACC, t), MAG: mag}
    with caplog.at_level(logging.WARNING, logger="hil.estimation.multirate"):
        steps, stats = merge(streams, MergePolicy(stale_after_s=0.105))
    assert stats.nan["mag"] == 40
    assert "nan samples of mag" in caplog.text
    stale = (steps.flags & StepFlag.MAG_STALE) != 0
    # last good sample at 0.18 s: usable through 0.285 s, stale after
    np.testing.assert_array_equal(stale, steps.t > 0.285)
    assert np.isnan(steps.mag[stale]).all() and not np.isnan(steps.mag[~stale]).any()


def test_a_stopped_driver_fails_over_to_the_next_sensor_and_back():
    gyr_t = np.r_[np.arange(0, 0.5, 0.005), np.arange(1.0, 1.5, 0.005)]  # the gyroscope stops for 0.5 s
    streams = {
        GYR: stream(GYR, gyr_t),
        ACC: stream(ACC, np.arange(0, 1.5, 0.01)),
        MAG: stream(MAG, np.arange(0, 1.5, 0.02)),
    }
    policy = MergePolicy(stale_after_s=0.1)
    steps, stats = merge(streams, policy)
    fail = (steps.flags & StepFlag.FAILOVER) != 0
    assert fail.any() and stats.failover_steps == fail.sum()
    assert np.all(steps.t[fail] > 0.495 + 0.1) and np.all(steps.t[fail] < 1.0)
    np.testing.assert_allclose(np.diff(steps.t[fail]), 0.01, atol=1e-12)  # at the accelerometer's rate
    assert np.all(steps.flags[fail] & StepFlag.GYR_STALE)
    assert np.all(steps.t[~fail][steps.t[~fail] > 0.6] >= 1.0)  # the gyroscope drives again on return
    assert stats.gaps == 1  # 0.495 → 0.6 (first failover step) is longer than gap_after_s
    assert_same(steps, live(streams, policy)[0])


def test_gaps_are_flagged_and_counted():
    t = np.r_[np.arange(0, 0.1, 0.01), np.arange(0.3, 0.4, 0.01)]
    steps, stats = merge(
        {GYR: stream(GYR, t), ACC: stream(ACC, t), MAG: stream(MAG, t)}, MergePolicy(failover=False)
    )
    assert stats.gaps == 1 and steps.flags[10] & StepFlag.GAP
    assert steps.h[10] == pytest.approx(0.21)


def test_live_latency_holds_steps_until_the_window_has_passed_and_uses_late_samples_next():
    policy = MergePolicy(latency_s=0.02)
    merger = Merger(policy)
    assert merger.push(SensorSample(0.0, GYR, (0, 0, 0))) == []
    assert merger.push(SensorSample(0.01, GYR, (1, 0, 0))) == []
    out = merger.push(SensorSample(0.02, ACC, (5, 0, 0)))  # watermark 0.02: the step at 0.0 is complete
    assert [s.t for s in out] == [0.0]
    out = merger.push(SensorSample(0.05, GYR, (2, 0, 0)))
    assert [s.t for s in out] == [0.01]
    out = merger.push(SensorSample(0.005, MAG, (9, 0, 0)))  # late, but newer than mag's held (none)
    assert out == [] and merger.stats.out_of_order["mag"] == 0
    rest = merger.flush()
    assert [s.t for s in rest] == [0.05]
    assert rest[0].mag == (9, 0, 0) and rest[0].fresh == (True, True, True)
    assert rest[0].age[MAG] == pytest.approx(0.045)


def test_policy_values_are_checked():
    with pytest.raises(ConfigError, match="stale_after_s"):
        MergePolicy(stale_after_s=-1)
    with pytest.raises(ConfigError, match="failover_order"):
        MergePolicy(driver=GYR, failover_order=(GYR, ACC))


# --------------------------------------------------------------------------- batch == live (property)
times = st.lists(st.floats(0.0, 2.0, allow_nan=False), min_size=0, max_size=40).map(sorted)


@st.composite
def messy_stream(draw, kind: SensorKind, allow_backwards: bool):
    t = list(draw(times))
    n = len(t)
    if n and draw(st.booleans()):  # duplicates
        for i in draw(st.lists(st.integers(0, n - 1), max_size=3)):
            t.insert(i, t[i])
    if allow_backwards and len(t) > 2 and draw(st.booleans()):  # a step back
        i = draw(st.integers(1, len(t) - 1))
        t[i], t[i - 1] = t[i - 1], t[i]
    xyz = np.array(draw(st.lists(st.tuples(*[st.floats(-50, 50)] * 3), min_size=len(t), max_size=len(t))))
    xyz = xyz.reshape(len(t), 3)
    for i in draw(st.lists(st.integers(0, max(len(t) - 1, 0)), max_size=2)) if len(t) else []:
        xyz[i, 1] = np.nan
    return SensorStream(kind, np.array(t, float), xyz)


def random_policy():
    return st.builds(
        MergePolicy,
        stale_after_s=st.sampled_from([0.05, 0.25, 1.0]),
        gap_after_s=st.sampled_from([0.02, 0.1]),
        failover=st.booleans(),
    )


@settings(max_examples=150, deadline=None)
@given(
    st.tuples(*[messy_stream(k, allow_backwards=True) for k in KINDS]),
    random_policy(),
    st.randoms(use_true_random=False),
)
def test_live_with_full_buffering_equals_batch_for_any_arrival_interleaving(streams3, policy, rnd):
    streams = dict(zip(KINDS, streams3, strict=True))
    batch, bstats = merge(streams, policy)
    queues = [list(s.samples()) for s in streams3]
    order = []
    while any(queues):
        q = rnd.choice([q for q in queues if q])
        order.append(q.pop(0))  # each sensor's own order kept, interleaving random
    got, lstats = live(streams, MergePolicy(**{**policy.__dict__, "latency_s": 1e9}), order)
    assert_same(batch, got)
    for name in (
        "accepted",
        "nan",
        "duplicate",
        "out_of_order",
        "stale_steps",
        "steps",
        "gaps",
        "failover_steps",
    ):
        assert getattr(bstats, name) == getattr(lstats, name), name


@settings(max_examples=100, deadline=None)
@given(st.tuples(*[messy_stream(k, allow_backwards=False) for k in KINDS]), random_policy())
def test_live_without_latency_equals_batch_when_samples_arrive_in_time_order(streams3, policy):
    streams = dict(zip(KINDS, streams3, strict=True))
    assert_same(merge(streams, policy)[0], live(streams, policy)[0])


# --------------------------------------------------------------------------- into the estimator
def test_estimator_runs_through_stale_nan_and_stopped_sensors_and_flags_them():
    t = np.arange(0, 3.0, 0.005)
    gyr = stream(GYR, t, [0.0, 0.0, 0.2])
    gyr.xyz[(t > 1.0) & (t < 1.6)] = np.nan  # gyroscope NaN for 0.6 s
    acc = stream(ACC, t[::2], [0.0, 0.0, 9.81])
    mag = stream(MAG, t[(t < 2.0)][::4], [0.0, 20.0, -40.0])  # magnetometer stops at 2 s
    steps, stats = merge({GYR: gyr, ACC: acc, MAG: mag})
    est = VariationalEstimator(EstimatorParams.paper())
    out = est.update_batch(steps)
    assert np.all(np.isfinite(out.R)) and np.all(np.isfinite(out.omega))
    assert np.any(out.flags & StepFlag.FAILOVER) and np.any(out.flags & StepFlag.MAG_STALE)
    assert est.stats.gyro_missing == stats.stale_steps["gyr"] > 0
    assert stats.nan["gyr"] == int(((t > 1.0) & (t < 1.6)).sum())
