"""Data: the canonical frames of the vectors, one or more per message of the catalogue.

Each :class:`GoodCase` is a message with the ``seq`` and ``flags`` to frame it with; :mod:`.build` turns
them into payload, frame and wire bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from ..messages import (
    ESC_CALIBRATION_CONFIRM,
    GIMBAL_ANGLE_LIMIT,
    GIMBAL_RATE_LIMIT,
    MAX_CALIBRATION_CHUNK,
    MAX_CHANNELS,
    MAX_UNITS,
    PROTOCOL_VERSION,
    PULSE_MAX_US,
    PULSE_MIN_US,
    ROTOR_SPEED_LIMIT,
    SCHEMA_HASH,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    ControlMode,
    Disarm,
    EscCalAbort,
    EscCalibrate,
    EscCalibrationStatus,
    EscCalPhase,
    EscCalStep,
    FaultFlag,
    Flags,
    GimbalMode,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Nack,
    NackReason,
    PowerState,
    RawPulses,
    ResetCause,
    SetMode,
    Severity,
    Telemetry,
    UnitSetpoint,
    UnitState,
    WatchdogState,
)

_F32 = struct.Struct("<f")


def _f32(x: float) -> float:
    """``x`` rounded to float32 (what the wire carries)."""
    return float(_F32.unpack(_F32.pack(x))[0])


@dataclass(frozen=True)
class GoodCase:
    """One canonical frame: ``message`` framed with ``seq`` and ``flags``; ``note`` goes into the file."""

    name: str
    message: Any
    seq: int = 0
    flags: int = 0
    note: str = ""


def good_cases() -> list[GoodCase]:
    """Every canonical frame, in file order (names are unique)."""
    units4 = tuple(
        UnitSetpoint(gimbal=_f32(g), rotor_speed=_f32(w))
        for g, w in ((0.5, 450.0), (-0.25, 450.0), (0.125, -300.5), (-1.0, 0.0))
    )
    states4 = tuple(
        UnitState(gimbal_angle=_f32(a), gimbal_rate=_f32(r), rotor_speed=_f32(w))
        for a, r, w in ((0.1, 0.5, 420.0), (-0.2, -0.25, 430.5), (3.0, 0.0, 0.0), (-6.283185, 1.5, -12.75))
    )
    long_text = "Δ" * 100  # 200 bytes of two-byte UTF-8
    return [
        GoodCase(
            "Hello/typical",
            Hello(
                protocol_version=PROTOCOL_VERSION,
                schema_hash=SCHEMA_HASH,
                manufacturer="vscmg-hil",
                model="hil-host",
                description="VSCMG HIL host",
                version="1.0",
                uri="https://example.invalid/vscmg",
                serial="HOST0001",
            ),
            seq=0,
            note="the host's first frame: version and schema hash of this catalogue",
        ),
        GoodCase(
            "Hello/empty_strings",
            Hello(protocol_version=255, schema_hash=0xFFFFFFFF),
            seq=255,
            flags=int(Flags.RETRANSMIT),
            note="every string empty (length byte 0); a retransmission",
        ),
        GoodCase(
            "Hello/max_lengths",
            Hello(
                protocol_version=1,
                schema_hash=0x00010000,
                manufacturer="M" * 24,
                model="m" * 24,
                description="d" * 48,
                version="v" * 16,
                uri="u" * 64,
                serial="s" * 24,
            ),
            seq=7,
            note="every identity string at its maximum length",
        ),
        GoodCase(
            "HelloReply/typical",
            HelloReply(
                protocol_version=PROTOCOL_VERSION,
                schema_hash=SCHEMA_HASH,
                reset_cause=ResetCause.WATCHDOG,
                state=BoardState.DISARMED,
                n_units=4,
                frame_rate_hz=50,
                boot_id=0x5A17C3E9,
                manufacturer="vscmg-hil",
                model="ADK-VSCMG",
                description="ADK board, 4 VSCMG units",
                version="1.0",
                uri="https://example.invalid/vscmg-hil",
                serial="SIM0001",
                firmware_build="fw 2024-01-01 µC",
            ),
            seq=0,
            note="after an MCU watchdog reset; firmware_build holds non-ASCII UTF-8",
        ),
        GoodCase(
            "HelloReply/max",
            HelloReply(
                protocol_version=255,
                schema_hash=0x80000000,
                reset_cause=ResetCause.SOFTWARE,
                state=BoardState.FAILSAFE,
                n_units=MAX_UNITS,
                frame_rate_hz=500,
                boot_id=0xFFFFFFFF,
                manufacturer="M" * 24,
                model="m" * 24,
                description="d" * 48,
                version="v" * 16,
                uri="u" * 64,
                serial="s" * 24,
                firmware_build="b" * 24,
            ),
            seq=200,
            note="the longest frame of the catalogue",
        ),
        GoodCase(
            "Heartbeat/host", Heartbeat(time_ms=0, state=0), seq=1, note="host heartbeat: state 0, boot id 0"
        ),
        GoodCase(
            "Heartbeat/board",
            Heartbeat(time_ms=0xDEADBEEF, state=int(BoardState.ARMED), boot_id=0x5A17C3E9),
            seq=128,
            note="board heartbeat: uptime in ms, state ARMED, the boot id of its HelloReply",
        ),
        GoodCase("Arm/typical", Arm(), seq=3, flags=int(Flags.ACK_REQUESTED), note="reliable, empty payload"),
        GoodCase(
            "Arm/retransmit",
            Arm(),
            seq=3,
            flags=int(Flags.ACK_REQUESTED | Flags.RETRANSMIT),
            note="the retry of Arm/typical: same seq, RETRANSMIT added",
        ),
        GoodCase("Disarm/typical", Disarm(), seq=4, flags=int(Flags.ACK_REQUESTED)),
        GoodCase(
            "SetMode/raw_pulses", SetMode(mode=ControlMode.RAW_PULSES), seq=5, flags=int(Flags.ACK_REQUESTED)
        ),
        GoodCase(
            "SetMode/esc_calibration",
            SetMode(mode=ControlMode.ESC_CALIBRATION),
            seq=6,
            flags=int(Flags.ACK_REQUESTED),
        ),
        GoodCase(
            "EscCalibrate/start",
            EscCalibrate(
                unit=2,
                step=EscCalStep.START,
                confirm=ESC_CALIBRATION_CONFIRM,
                low_us=1000,
                high_us=2000,
                supply_off_ms=1500,
                high_ms=3000,
                low_ms=2000,
            ),
            seq=7,
            flags=int(Flags.ACK_REQUESTED),
            note="teach unit 2's ESC 1000..2000 us, confirmed (the confirm field is ASCII 'UNLD')",
        ),
        GoodCase(
            "EscCalibrate/supply_applied",
            EscCalibrate(unit=2, step=EscCalStep.SUPPLY_APPLIED, confirm=ESC_CALIBRATION_CONFIRM),
            seq=8,
            flags=int(Flags.ACK_REQUESTED),
            note="the operator connected the ESC's supply (boards without a supply switch)",
        ),
        GoodCase(
            "EscCalibrate/unconfirmed",
            EscCalibrate(
                unit=0, confirm=0, low_us=PULSE_MIN_US, high_us=PULSE_MAX_US, high_ms=100, low_ms=100
            ),
            seq=12,
            flags=int(Flags.ACK_REQUESTED),
            note="well formed, but a board NACKs it UNCONFIRMED",
        ),
        GoodCase("Ack/typical", Ack(msg_id=Arm.MSG_ID, seq=3), seq=9, note="answers Arm/typical"),
        GoodCase("Ack/zero_fields", Ack(msg_id=0, seq=0), seq=0, note="payload of zeros: COBS at work"),
        GoodCase("Nack/power", Nack(msg_id=Arm.MSG_ID, seq=3, reason=NackReason.POWER), seq=10),
        GoodCase(
            "Nack/bad_calibration",
            Nack(msg_id=CalibrationData.MSG_ID, seq=255, reason=NackReason.BAD_CALIBRATION),
            seq=11,
        ),
        GoodCase(
            "ActuatorSetpoint/4_units_rate",
            ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=units4),
            seq=42,
            note="the paper's 4-unit pyramid: gimbal rates (rad/s) and rotor speeds (rad/s)",
        ),
        GoodCase(
            "ActuatorSetpoint/1_unit_angle_limits",
            ActuatorSetpoint(
                gimbal_mode=GimbalMode.ANGLE,
                units=(UnitSetpoint(gimbal=-GIMBAL_ANGLE_LIMIT, rotor_speed=ROTOR_SPEED_LIMIT),),
            ),
            seq=43,
            note="one unit, both fields at their range limits",
        ),
        GoodCase(
            "ActuatorSetpoint/8_units_zero",
            ActuatorSetpoint(units=(UnitSetpoint(),) * MAX_UNITS),
            seq=44,
            note="the most units; all-zero floats",
        ),
        GoodCase(
            "RawPulses/8_channels",
            RawPulses(pulses_us=(1500, 1000, 1500, 1250, 1500, 1750, 1480, 2000)),
            seq=12,
            note="gimbal 0, rotor 0, gimbal 1, rotor 1, ...",
        ),
        GoodCase(
            "RawPulses/limits",
            RawPulses(pulses_us=(PULSE_MIN_US,) + (PULSE_MAX_US,) * (MAX_CHANNELS - 1)),
            seq=13,
            note="16 channels at the pulse-width limits",
        ),
        GoodCase(
            "CalibrationData/first_fragment",
            CalibrationData(
                unit=2,
                transfer_id=9,
                index=0,
                count=3,
                total_len=450,
                set_crc=0x1D0F,
                chunk=bytes(range(MAX_CALIBRATION_CHUNK)),
            ),
            seq=20,
            flags=int(Flags.ACK_REQUESTED),
            note="a full 200-byte chunk, including zero bytes",
        ),
        GoodCase(
            "CalibrationData/last_fragment",
            CalibrationData(
                unit=2,
                transfer_id=9,
                index=2,
                count=3,
                total_len=450,
                set_crc=0x1D0F,
                chunk=bytes([0xFF] * 50),
            ),
            seq=22,
            flags=int(Flags.ACK_REQUESTED),
        ),
        GoodCase(
            "CalibrationData/empty_set",
            CalibrationData(
                unit=MAX_UNITS - 1, transfer_id=0, index=0, count=1, total_len=0, set_crc=0xFFFF, chunk=b""
            ),
            seq=23,
            flags=int(Flags.ACK_REQUESTED),
            note="a zero-length set: one empty fragment",
        ),
        GoodCase(
            "CalibrationRequest/typical",
            CalibrationRequest(unit=1, transfer_id=200),
            seq=30,
            flags=int(Flags.ACK_REQUESTED),
        ),
        GoodCase(
            "Telemetry/4_units",
            Telemetry(
                time_ms=123456,
                state=BoardState.ARMED,
                mode=ControlMode.SETPOINT,
                watchdog=WatchdogState.OK,
                power=PowerState.WARN,
                faults=int(FaultFlag.BATTERY_LOW | FaultFlag.SETPOINT_CLAMPED),
                link_age_ms=20,
                battery_mv=11480,
                battery_ma=2350,
                battery_soc=63,
                ubec_mv=5010,
                ubec_ma=870,
                rx_frames=100000,
                rx_bad=3,
                seq_gaps=1,
                pulses_us=(1500, 1400, 1510, 1400, 1490, 1420, 1500, 1380),
                units=states4,
            ),
            seq=77,
            note="4 units, 8 channels",
        ),
        GoodCase("Telemetry/boot_empty", Telemetry(), seq=0, note="no channels, no units, everything zero"),
        GoodCase(
            "Telemetry/failsafe_max",
            Telemetry(
                time_ms=0xFFFFFFFF,
                state=BoardState.FAILSAFE,
                mode=ControlMode.RAW_PULSES,
                watchdog=WatchdogState.LINK_LOST,
                power=PowerState.BROWN_OUT,
                faults=0xFFFF,
                link_age_ms=0xFFFF,
                battery_mv=0xFFFF,
                battery_ma=0xFFFF,
                battery_soc=100,
                ubec_mv=0xFFFF,
                ubec_ma=0xFFFF,
                rx_frames=0xFFFFFFFF,
                rx_bad=0xFFFFFFFF,
                seq_gaps=0xFFFFFFFF,
                pulses_us=(PULSE_MAX_US,) * MAX_CHANNELS,
                units=(
                    UnitState(
                        gimbal_angle=GIMBAL_ANGLE_LIMIT,
                        gimbal_rate=-GIMBAL_RATE_LIMIT,
                        rotor_speed=-ROTOR_SPEED_LIMIT,
                    ),
                )
                * MAX_UNITS,
            ),
            seq=255,
            note="every field at its maximum (negative limits for the floats)",
        ),
        GoodCase(
            "EscCalibrationStatus/high",
            EscCalibrationStatus(
                unit=2,
                phase=EscCalPhase.HIGH,
                abort=EscCalAbort.NONE,
                pulse_us=2000,
                supply_on=1,
                phase_ms=1250,
            ),
            seq=78,
            note="unit 2's ESC powered at its high endpoint for 1.25 s",
        ),
        GoodCase(
            "EscCalibrationStatus/aborted",
            EscCalibrationStatus(
                unit=7,
                phase=EscCalPhase.ABORTED,
                abort=EscCalAbort.LINK_LOST,
                pulse_us=1000,
                supply_on=1,
                phase_ms=0xFFFFFFFF,
            ),
            seq=79,
            note="aborted by the link watchdog: the channel at the safe pulse",
        ),
        GoodCase("Log/info", Log(severity=Severity.INFO, code=2, text="state DISARMED -> ARMED"), seq=50),
        GoodCase(
            "Log/max_text",
            Log(severity=Severity.CRITICAL, code=0xFFFF, text=long_text),
            seq=51,
            note="200 bytes of UTF-8 (100 × 'Δ')",
        ),
        GoodCase("Log/empty", Log(severity=Severity.DEBUG, code=0, text=""), seq=52),
    ]
