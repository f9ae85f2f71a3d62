"""The ESC endpoint procedure's width on the pins and in ``Telemetry.pulses_us`` as it ends, on the
emulator (the firmware's specification) and on the C firmware under simavr side by side.

Every phase change of the procedure (its start, its steps, its end or abort) makes the board aim its
outputs again in that main-loop pass (the firmware's ``esc_cal.c`` ``enter`` sets ``outputs_dirty``;
the emulator's ``EscCalibration`` calls the board's ``_apply_outputs``): no ``Telemetry`` reports mode
SETPOINT while ``pulses_us`` still shows the procedure's endpoint (after an abort in HIGH, the high
endpoint: full throttle, shown as the present output). Before, the emulator re-aimed only at the next
pulse frame start and said so for up to a frame. And a load shed that aborts the procedure is logged the
same way on both: the power stage first, then the abort."""

from __future__ import annotations

import pytest
from conformance.host import heartbeat, lockstep
from test_firmware_differential import Pair, hello

from firmware_sim.board.config import BoardConfig
from protocol.messages import (
    ESC_CALIBRATION_CONFIRM,
    Ack,
    ControlMode,
    Disarm,
    EscCalibrate,
    EscCalPhase,
    Heartbeat,
    Log,
    Telemetry,
)

SWITCHED = BoardConfig(n_units=2, frame_rate_hz=50.0, telemetry_rate_hz=100.0, esc_supply_switch=True)
"""Telemetry twice a pulse frame: every other one falls in the middle of a frame, where a width aimed
only at the next frame start would still be the procedure's."""
UNIT = 1
CHANNEL = 2 * UNIT + 1


def teach(unit: int = UNIT, **kw) -> EscCalibrate:
    fields = {"low_us": 1100, "high_us": 1900, "supply_off_ms": 150, "high_ms": 200, "low_ms": 200} | kw
    return EscCalibrate(unit=unit, confirm=ESC_CALIBRATION_CONFIRM, **fields)


def stale(received, safe: int, channel: int = CHANNEL) -> list[tuple[int, str, int]]:
    """The telemetry that says the procedure is over (mode not ESC_CALIBRATION) yet still reports a width
    other than the safe pulse on the procedure's channel."""
    return [
        (m.time_ms, m.mode.name, m.pulses_us[channel])
        for m in received
        if isinstance(m, Telemetry)
        and m.mode is not ControlMode.ESC_CALIBRATION
        and m.state.name != "ARMED"
        and m.pulses_us[channel] != safe
    ]


# --------------------------------------------------------------------------- the emulator (the spec)
@pytest.mark.parametrize("offset_ms", [0, 3, 7, 11, 16])
@pytest.mark.parametrize("end", ["disarm", "hello", "link_lost", "done"])
def test_the_emulator_reports_the_safe_width_as_soon_as_the_procedure_ends(end, offset_ms):
    board, clock, host = lockstep(SWITCHED)
    host.max_step = 0.001
    host.handshake()
    host.keepalive = heartbeat
    assert isinstance(host.request(teach()), Ack)
    host.poll(0.2 + offset_ms / 1000)  # HIGH: the channel at the high endpoint
    assert board.esc_calibration.phase is EscCalPhase.HIGH
    assert board.targets[CHANNEL] is not None
    if end in ("disarm", "hello"):
        if end == "disarm":
            host.request(Disarm())
        else:
            host.handshake()
        # aimed in the pass that ended it: what telemetry reports and the next frame dithers is safe
        assert not board.esc_calibration.active
        assert board.targets[CHANNEL] == board._compute_outputs()[0][CHANNEL]
    elif end == "link_lost":
        host.keepalive = None
        host.poll(SWITCHED.link_timeout_s + 0.05)
        host.keepalive = heartbeat
    host.poll(0.5 if end == "done" else 0.1)
    assert not board.esc_calibration.active
    assert board.esc_calibration.phase in (EscCalPhase.ABORTED, EscCalPhase.DONE)
    assert stale(host.received, SWITCHED.rotor_safe_us) == []


def test_the_emulator_aims_the_outputs_at_every_phase_change():
    board, clock, host = lockstep(SWITCHED)
    host.max_step = 0.001
    host.handshake()
    host.keepalive = heartbeat
    calls: list[EscCalPhase] = []
    apply = board._apply_outputs

    def spy() -> None:
        calls.append(board.esc_calibration.phase)
        apply()

    board.esc_calibration._on_change = spy
    assert isinstance(host.request(teach()), Ack)
    host.poll(0.7)
    assert calls == [EscCalPhase.SUPPLY_OFF, EscCalPhase.HIGH, EscCalPhase.LOW, EscCalPhase.DONE]


# --------------------------------------------------------------------------- firmware against emulator
def _logs(pair: Pair, which: str) -> list[Log]:
    return [m for m in pair.received[which] if isinstance(m, Log)]


class _Recording(Pair):
    """The differential pair, keeping every message each board sent."""

    def __init__(self, config: BoardConfig) -> None:
        super().__init__(config)
        self.received: dict[str, list] = {k: [] for k in self.boards}

    def _drain(self) -> None:
        from protocol.frame import BadFrame

        for k, b in self.boards.items():
            out = b.take_output()
            for e in self.deframers[k].feed(out):
                assert not isinstance(e, BadFrame), f"{k} sent a bad frame: {e}"
                self.received[k].append(e.message)


@pytest.mark.firmware
@pytest.mark.parametrize("end", ["disarm", "hello", "done"])
def test_neither_board_reports_the_endpoint_width_after_the_procedure_ends(end):
    cfg = SWITCHED
    for offset_ms in (0, 5, 9, 14):
        pair = _Recording(cfg)
        try:
            pair.run(0.15)
            pair.send(hello())
            pair.run(0.1)
            pair.send(teach(), 1)
            pair.run(0.2 + offset_ms / 1000)
            pair.send(Heartbeat(time_ms=0, state=0))
            pair.run(0.1)
            if end == "disarm":
                pair.send(Disarm(), 1)
            elif end == "hello":
                pair.send(hello())
            for _ in range(6):
                pair.run(0.05)
                pair.send(Heartbeat(time_ms=0, state=0))
            for which in pair.boards:
                modes = [m.mode for m in pair.received[which] if isinstance(m, Telemetry)]
                assert ControlMode.ESC_CALIBRATION in modes, which
                assert modes[-1] is ControlMode.SETPOINT, which
                assert stale(pair.received[which], cfg.rotor_safe_us) == [], (which, offset_ms)
        finally:
            pair.close()


@pytest.mark.firmware
def test_a_load_shed_that_aborts_the_procedure_is_logged_in_the_same_order_on_both():
    pair = _Recording(SWITCHED)
    try:
        pair.run(0.15)
        pair.send(hello())
        pair.run(0.1)
        t0 = pair.clock.now()
        for b in pair.boards.values():
            b.faults.sag(drop_v=3.5, at=t0 + 0.5, duration=1.0)
        pair.send(teach(high_ms=3000, supply_off_ms=200), 1)
        for _ in range(40):
            pair.send(Heartbeat(time_ms=0, state=0))
            pair.run(0.05)
        order = {}
        for which in pair.boards:
            texts = [m.text for m in _logs(pair, which)]
            shed = next(i for i, t in enumerate(texts) if "-> SHED" in t)
            aborted = next(i for i, t in enumerate(texts) if "aborted (POWER)" in t)
            order[which] = [t.split(" (")[0] for t in texts[min(shed, aborted) : max(shed, aborted) + 1]]
            assert shed < aborted, (which, texts)
        assert order["firmware"] == order["emulator"]
    finally:
        pair.close()
