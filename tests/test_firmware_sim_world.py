"""The emulator's world (firmware_sim.world.World) on the compiled plant and phone against the same world on
the numpy references, next to a board driven through the protocol in lockstep: the same phone samples and
truth to rounding; batches from one board event to the next whatever the caller's chunks; the board's
events, power and telemetry following the physics; a dispersed true spacecraft flown; the gimbals' angle
mode and undriven rotors."""

from __future__ import annotations

import contextlib
from dataclasses import astuple, replace

import numpy as np
import pytest

from hil import so3
from hil.vscmg import cubesat_1u
from protocol.errors import BoardReset
from protocol.messages import ActuatorSetpoint, GimbalMode, UnitSetpoint


def _rig(compiled: bool, scenario=None, seed=None):
    """A world on a board in lockstep, the board armed through the protocol by a host."""
    from firmware_sim.servers.transports import EmulatorTransport
    from firmware_sim.world import World
    from hil.link.board import BoardClient
    from hil.scenario import load_scenario
    from hil.timing.clock import LockstepClock

    scenario = scenario or load_scenario("cubesat-1u")
    clock = LockstepClock()
    link = EmulatorTransport(scenario.emulator_url(), clock)
    client = BoardClient(link, clock=clock)
    client.connect()
    world = World(scenario, link.board, seed=seed, compiled=compiled)
    client.arm()
    return clock, client, world


def _drive(
    compiled: bool,
    seconds: float,
    chunk: float = 0.005,
    period: float = 0.005,
    mode=GimbalMode.RATE,
    faults=None,
    scenario=None,
):
    """The world driven for ``seconds``: rotors spun up, gimbals turned both ways (or to angles), the world
    advanced every ``chunk`` s and a setpoint sent every ``period`` s; ``faults(board)`` schedules faults
    first. Returns the phone samples, truths (every 0.1 s) and the world."""
    clock, client, world = _rig(compiled, scenario)
    if faults is not None:
        faults(world.board)
    samples, truths = [], []
    k_period = round(period / chunk)
    for k in range(round(seconds / chunk)):
        clock.advance(chunk)
        samples += world.advance_to(clock.now())
        if (k + 1) % k_period == 0:  # at the same clock times whatever the chunk
            t = (k + 1) * chunk
            if mode is GimbalMode.RATE:
                gimbal = (0.5 * np.sin(2.0 * t), -0.4 * np.cos(1.5 * t), 0.3, -0.2 * np.sin(t))
            else:
                gimbal = (0.6, -0.8 * np.cos(t), 1.2, -1.0)
            speeds = (300.0 + 40 * t, 250.0, 350.0 - 20 * t, 300.0)
            units = tuple(UnitSetpoint(g, w) for g, w in zip(gimbal, speeds, strict=True))
            with contextlib.suppress(BoardReset):  # a reset board stays disarmed: this host does not re-arm
                client.send_setpoint(ActuatorSetpoint(gimbal_mode=mode, units=units))
            client.service()
        if round((k + 1) * chunk / 0.1, 9).is_integer():
            truths.append(world.truth())
    client.close()
    return samples, truths, world


def _same_samples(a, b, atol=1e-9):
    assert len(a) == len(b) > 0
    for x, y in zip(a, b, strict=True):
        assert x.kind == y.kind and x.t_s == y.t_s
        np.testing.assert_allclose(x.xyz, y.xyz, rtol=0, atol=atol * max(1.0, float(np.max(np.abs(y.xyz)))))


def _same_truths(a, b, atol=1e-9):
    assert len(a) == len(b) > 0
    for x, y in zip(a, b, strict=True):
        assert x.t == y.t
        for name in ("R", "omega", "gimbal_angle", "gimbal_rate"):
            np.testing.assert_allclose(getattr(x, name), getattr(y, name), rtol=0, atol=atol)
        np.testing.assert_allclose(x.rotor_speed, y.rotor_speed, rtol=atol)


def test_the_compiled_world_gives_the_reference_worlds_phone_samples_and_truth():
    fast_samples, fast_truth, world = _drive(True, 3.0)
    ref_samples, ref_truth, ref_world = _drive(False, 3.0)
    assert world.compiled is not None and ref_world.compiled is None
    assert world.steps == ref_world.steps == 3000
    assert world.batches == ref_world.batches < 1000  # several plant steps per batch
    _same_samples(fast_samples, ref_samples)
    _same_truths(fast_truth, ref_truth)
    # the board drove the plant: rotors spun up, gimbals turned, the body moved
    last = fast_truth[-1]
    assert np.min(last.rotor_speed) > 100.0
    assert np.max(np.abs(last.gimbal_angle - fast_truth[0].gimbal_angle)) > 0.1
    assert so3.angle_between(last.R, fast_truth[0].R) > 1e-3
    # the state is the plant's state, built from the flat one; the board holds the same unit states
    s, truth = world.state, world.truth()
    assert s.batch == 1 and s.t == pytest.approx(world.now - world.t0)
    np.testing.assert_array_equal(s.R[0], truth.R)
    np.testing.assert_array_equal(s.omega[0], truth.omega)
    np.testing.assert_allclose(
        [astuple(u) for u in world.unit_states()], [astuple(u) for u in ref_world.unit_states()], atol=1e-9
    )
    assert [astuple(u) for u in world.board.unit_states()] == [astuple(u) for u in world.unit_states()]


def test_gimbals_on_angles_reach_them_and_match_the_reference():
    fast_samples, fast_truth, world = _drive(True, 2.0, mode=GimbalMode.ANGLE)
    ref_samples, ref_truth, _ = _drive(False, 2.0, mode=GimbalMode.ANGLE)
    _same_samples(fast_samples, ref_samples)
    _same_truths(fast_truth, ref_truth)
    angles = fast_truth[-1].gimbal_angle
    # the servos' position loops brought the gimbals to the angles the pulses stand for (the pulses'
    # resolution and the body's motion leave a few milliradians)
    np.testing.assert_allclose(angles[[0, 2, 3]], [0.6, 1.2, -1.0], atol=0.02)


def test_how_the_caller_chunks_time_does_not_change_the_world():
    """The board's events fall at the same plant steps, and the board runs only at its own events and
    when the host's I/O steps it, whether the world is advanced every plant step (the lockstep runtime's
    plant task), every 5 ms or every 20 ms: the same samples and truth to rounding, and one compiled
    batch per pulse frame whatever the chunks (50 Hz frames). The world also hands the board its unit
    states at the end of each call (for a host that steps the board before the world's next call), with
    the rotors' accelerations over their last plant step: the board's power draw, and through the
    battery's sag the ESCs' speeds, do not depend on when the hand-overs come."""
    runs = {chunk: _drive(True, 1.0, chunk=chunk, period=0.02) for chunk in (0.001, 0.005, 0.02)}
    (s1, t1, w1), (s5, t5, w5), (s20, t20, w20) = runs.values()
    _same_samples(s1, s5, atol=1e-12)
    _same_samples(s1, s20, atol=1e-12)
    _same_truths(t1, t5, atol=1e-12)
    _same_truths(t1, t20, atol=1e-12)
    assert w1.steps == w5.steps == w20.steps == 1000
    assert w1.batches == w5.batches == w20.batches <= 52
    assert w1.rewinds == w5.rewinds == w20.rewinds == 0


def test_steps_taken_ahead_are_dropped_when_the_board_changes_its_pulses_between_frames(monkeypatch):
    """The world steps ahead to the next pulse frame; a rotor ESC that dies between frames and an MCU hang
    whose watchdog resets the board (outputs off) change the drives at once: the world drops what it
    stepped ahead and steps again from there — the same samples and truth as a world that steps one plant
    step at a time and is called every step (its drives read the board after every step)."""
    import firmware_sim.world.world as world_module

    def faults(board):
        board.faults.dead_esc(1, at=board.now + 0.1137)  # unit 0's rotor ESC, while it spins up
        board.faults.hang(at=board.now + 0.6213)

    fast_samples, fast_truth, fast = _drive(True, 1.5, chunk=0.005, faults=faults)
    monkeypatch.setattr(world_module, "LOOK_AHEAD_S", 1e-4)  # shorter than a plant step: one at a time
    ref_samples, ref_truth, ref = _drive(True, 1.5, chunk=0.001, faults=faults)
    assert fast.rewinds >= 2 and ref.rewinds == 0
    assert ref.batches == ref.steps == fast.steps == 1500 and fast.batches < 200
    assert [r.cause.name for r in fast.board.resets[1:]] == ["WATCHDOG"]
    _same_samples(fast_samples, ref_samples, atol=1e-12)
    _same_truths(fast_truth, ref_truth, atol=1e-12)


def test_the_board_follows_the_world_at_its_own_events():
    """The board's telemetry reports the unit states the world handed over at its events, and its power
    draw follows the rotors the world spins up."""
    clock, client, world = _rig(True)
    board = world.board
    idle_a = board.power.battery_a
    units = tuple(UnitSetpoint(0.2, 400.0) for _ in range(4))
    for _ in range(300):
        clock.advance(0.005)
        world.advance_to(clock.now())
        client.send_setpoint(ActuatorSetpoint(units=units))
        client.service()
    truth = world.truth()
    assert np.all(truth.rotor_speed > 300.0)
    assert board.power.battery_a > idle_a + 0.1  # the ESCs draw what spinning rotors cost
    telemetry = client.telemetry
    assert telemetry is not None
    reported = np.array([u.rotor_speed for u in telemetry.units])
    assert np.all(np.abs(reported - truth.rotor_speed) < 0.05 * truth.rotor_speed)  # ≤ one 50 ms period
    assert world.now <= board.now < world.now + world.step_s  # the host's I/O steps it to the clock's now
    client.close()


def test_a_dispersed_true_spacecraft_is_what_the_world_flies():
    from hil.scenario import load_scenario

    base = load_scenario("cubesat-1u")
    heavy = replace(cubesat_1u(), bus_inertia=(4.0e-3, 4.2e-3, 4.4e-3))
    scenario = base.with_changes(true_spacecraft=heavy)
    _, _, world = _rig(True, scenario)
    assert world.params is heavy
    assert world.plant.params is heavy and world.compiled is not None
    np.testing.assert_allclose(
        world.plant.locked_inertia(world.state)[0].diagonal(), [4e-3, 4.2e-3, 4.4e-3], rtol=0.05
    )


def test_truth_is_cheap_and_independent_of_the_state():
    clock, client, world = _rig(True)
    clock.advance(0.05)
    world.advance_to(clock.now())
    a = world.truth()
    a.R[:] = 0.0  # a copy: writing to it does not touch the world
    b = world.truth()
    assert so3.is_rotation(b.R)
    assert b.t == world.now
    client.close()


def test_a_short_world_run_equals_the_reference_world():
    """0.3 s of the driven world on either plant (short enough for the compiler switched off)."""
    fast_samples, fast_truth, world = _drive(True, 0.3)
    ref_samples, ref_truth, _ = _drive(False, 0.3)
    _same_samples(fast_samples, ref_samples)
    _same_truths(fast_truth, ref_truth)
    assert world.steps == 300 and len(fast_samples) > 100


def test_a_finer_plant_step_than_a_batch_had_room_for():
    """A 0.25 ms plant step: 80 steps to the next pulse frame, more than the world first made room for —
    the same samples and truth as the reference world."""
    from hil.scenario import load_scenario

    base = load_scenario("cubesat-1u")
    fine = base.with_changes(loop=replace(base.loop, plant_step_s=2.5e-4))
    fast_samples, fast_truth, world = _drive(True, 0.3, scenario=fine)
    ref_samples, ref_truth, _ = _drive(False, 0.3, scenario=fine)
    _same_samples(fast_samples, ref_samples)
    _same_truths(fast_truth, ref_truth)
    assert world.steps == round((world.now - world.t0) / 2.5e-4) >= 1200 and world.batches <= 17
    assert np.all(fast_truth[-1].rotor_speed > 50.0)
