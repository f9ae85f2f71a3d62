"""The wire protocol against MAVLink v2 (pymavlink), side by side in one run:

* encode and decode rate (frames/s) of a 4-unit ``ActuatorSetpoint`` (34-byte payload) against
  MAVLink's ``OPTICAL_FLOW`` (34 bytes), and of a 4-unit, 8-channel ``Telemetry`` (99 bytes) against
  ``CONTROL_SYSTEM_STATE`` (100 bytes, the nearest common message). Encode = message object → wire bytes
  (ours ``Framer.encode``, theirs ``msg.pack``); decode = a buffer of 100 frames → message objects
  (ours ``Deframer.feed``, theirs ``MAVLink.parse_buffer``), per frame;
* the same decode rates with the C extension switched off (``protocol.speedups``' pure-Python COBS and
  CRC, as ``PROTOCOL_PURE=1`` gives), against the same peer: what a machine without a C compiler gets;
* COBS in C (``protocol._speedups``) against the pure-Python reference (``protocol.cobs``) on a frame;
* wire bytes per frame;
* DESIGN.md's claim: at 1 % byte errors, frames lost *beyond* the damaged ones — ours (COBS + CRC) vs
  MAVLink v2 (length-prefixed), on the same random corruption of a long mixed stream;
* the atheris fuzz harness's inputs/s (``bench/fuzz_deframer.py`` in a subprocess: libFuzzer needs its
  own process).

pymavlink runs its pure-Python parser (its default; ``use_native=False``), with its CRC in native code
(``fastcrc``, when installed, as here); ours is Python with COBS and CRC in C (``protocol._speedups``).
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

import protocol.frame
from bench.common import Result, fuzz_rate, rate
from protocol import cobs, speedups
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    ActuatorSetpoint,
    BoardState,
    GimbalMode,
    PowerState,
    Telemetry,
    UnitSetpoint,
    UnitState,
    encode_payload,
)

NAME = "protocol"
PEER = "pymavlink 2 (MAVLink v2)"
BATCH = 100
BYTE_ERROR_RATE = 0.01
FUZZ = Path(__file__).resolve().parent / "fuzz_deframer.py"


# =========================================================================== the messages
def setpoint() -> ActuatorSetpoint:
    units = tuple(UnitSetpoint(gimbal=0.25 * (i + 1), rotor_speed=400.0 + 10 * i) for i in range(4))
    return ActuatorSetpoint(gimbal_mode=GimbalMode.RATE, units=units)


def telemetry() -> Telemetry:
    return Telemetry(
        time_ms=123456, state=BoardState.ARMED, power=PowerState.NORMAL, link_age_ms=12, battery_mv=11800,
        battery_ma=2300, battery_soc=80, ubec_mv=5000, ubec_ma=900, rx_frames=12345, rx_bad=2, seq_gaps=1,
        pulses_us=(1500, 1400, 1510, 1420, 1490, 1410, 1505, 1430),
        units=tuple(UnitState(0.125 * i, 0.5, 420.0 + i) for i in range(4)),  # float32-exact
    )  # fmt: skip


def optical_flow() -> Any:
    return mavlink2.MAVLink_optical_flow_message(
        time_usec=1_234_567, sensor_id=1, flow_x=12, flow_y=-34, flow_comp_m_x=0.1, flow_comp_m_y=0.2,
        quality=200, ground_distance=1.5, flow_rate_x=1.25, flow_rate_y=2.5,
    )  # fmt: skip


def control_system_state() -> Any:
    return mavlink2.MAVLink_control_system_state_message(
        time_usec=123_456_789, x_acc=0.1, y_acc=0.2, z_acc=9.8, x_vel=1.0, y_vel=2.0, z_vel=3.0, x_pos=4.0,
        y_pos=5.0, z_pos=6.0, airspeed=7.0, vel_variance=[0.1, 0.2, 0.3], pos_variance=[0.4, 0.5, 0.6],
        q=[1.0, 0.0, 0.0, 0.0], roll_rate=0.01, pitch_rate=0.02, yaw_rate=0.03,
    )  # fmt: skip


def _mav() -> Any:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.robust_parsing = True  # bad data becomes a BAD_DATA message instead of an exception
    return mav


# =========================================================================== rates and sizes
def _codec_results(label: str, ours_msg: Any, theirs_msg: Any, min_time: float) -> list[Result]:
    framer = Framer()
    mav = _mav()
    ours_wire = framer.encode(ours_msg)[1]
    theirs_wire = theirs_msg.pack(mav)
    payload = len(encode_payload(ours_msg))
    peer_payload = len(theirs_wire) - 12
    peer = f"{PEER} {theirs_msg.get_type()} ({peer_payload} B)"
    ours_batch = b"".join(framer.encode(ours_msg)[1] for _ in range(BATCH))
    theirs_batch = b"".join(theirs_msg.pack(mav) for _ in range(BATCH))

    def ours_decode() -> None:
        events = Deframer().feed(ours_batch)
        assert len(events) == BATCH and isinstance(events[-1], Frame)

    def theirs_decode() -> None:
        msgs = _mav().parse_buffer(theirs_batch)
        assert msgs is not None and len(msgs) == BATCH

    note = f"payload {payload} B vs {peer_payload} B"
    return [
        Result(NAME, f"encode {label}", rate(lambda: framer.encode(ours_msg), min_time), "frames/s", peer,
               rate(lambda: theirs_msg.pack(mav), min_time), note=note),
        Result(NAME, f"decode {label}", BATCH * rate(ours_decode, min_time), "frames/s", peer,
               BATCH * rate(theirs_decode, min_time), note=note),
        Result(NAME, f"wire bytes {label}", len(ours_wire), "B", peer, len(theirs_wire),
               higher_is_better=False),
    ]  # fmt: skip


@contextmanager
def _pure_python() -> Iterator[None]:
    """The frame codec on the pure-Python COBS and CRC, as with ``PROTOCOL_PURE=1`` (without a subprocess:
    the two names :mod:`protocol.frame` takes from :mod:`protocol.speedups`, swapped for the run)."""
    saved = protocol.frame.seal, protocol.frame.unseal
    protocol.frame.seal, protocol.frame.unseal = speedups.seal_reference, speedups.unseal_reference
    try:
        yield
    finally:
        protocol.frame.seal, protocol.frame.unseal = saved


def _pure_decode_results(label: str, ours_msg: Any, theirs_msg: Any, min_time: float) -> list[Result]:
    """The decode row again, ours without the C extension."""
    mav = _mav()
    ours_batch = b"".join(Framer().encode(ours_msg)[1] for _ in range(BATCH))
    theirs_batch = b"".join(theirs_msg.pack(mav) for _ in range(BATCH))

    def ours_decode() -> None:
        assert len(Deframer().feed(ours_batch)) == BATCH

    with _pure_python():
        ours = BATCH * rate(ours_decode, min_time)
    theirs = BATCH * rate(lambda: _mav().parse_buffer(theirs_batch), min_time)
    return [
        Result(NAME, f"decode {label}, pure-Python COBS/CRC", ours, "frames/s",
               f"{PEER} {theirs_msg.get_type()}", theirs, note="as PROTOCOL_PURE=1 or no C compiler gives"),
    ]  # fmt: skip


def _cobs_results(msg: Any, min_time: float) -> list[Result]:
    """COBS alone on one frame (header + payload + CRC) of ``msg``: C against the Python reference."""
    wire = Framer().encode(msg)[1]
    frame = cobs.decode(wire[:-1])
    encoded = wire[:-1]
    assert speedups.NATIVE, "protocol._speedups is not built (or PROTOCOL_PURE is set)"
    peer = "protocol.cobs (pure Python)"
    note = f"{type(msg).__name__}: {len(frame)}-byte frame, {len(encoded)} bytes encoded"
    c_encode, c_decode = speedups.cobs_encode, speedups.cobs_decode
    return [
        Result(NAME, "COBS encode (C)", rate(lambda: c_encode(frame), min_time), "frames/s", peer,
               rate(lambda: cobs.encode(frame), min_time), note=note),
        Result(NAME, "COBS decode (C)", rate(lambda: c_decode(encoded), min_time), "frames/s", peer,
               rate(lambda: cobs.decode(encoded), min_time), note=note),
    ]  # fmt: skip


# =========================================================================== loss at 1 % byte errors
def _corrupt(frames: Sequence[bytes], p: float, rng: random.Random) -> tuple[bytes, set[int]]:
    """The concatenated frames with each byte replaced by another value with probability ``p``; and the
    indices of the frames that were hit."""
    out = bytearray()
    damaged = set()
    for i, frame in enumerate(frames):
        buf = bytearray(frame)
        for j in range(len(buf)):
            if rng.random() < p:
                buf[j] ^= rng.randrange(1, 256)
                damaged.add(i)
        out += buf
    return bytes(out), damaged


def _recovered(
    sent: Sequence[Any], received: Sequence[Any], same: Callable[[Any, Any], bool]
) -> tuple[set, int]:
    """Indices of ``sent`` found in ``received`` (in order), and how many received items matched none
    (corrupt frames that passed the checksum: false accepts)."""
    found: set[int] = set()
    false_accepts = 0
    j = 0
    for item in received:
        for k in range(j, min(j + 512, len(sent))):
            if same(sent[k], item):
                found.add(k)
                j = k + 1
                break
        else:
            false_accepts += 1
    return found, false_accepts


def _loss_ours(n: int, rng: random.Random) -> tuple[int, int, int]:
    framer = Framer()
    msgs = [setpoint() if i % 2 else telemetry() for i in range(n)]
    frames = [framer.encode(m)[1] for m in msgs]
    sent = list(enumerate(msgs))
    stream, damaged = _corrupt(frames, BYTE_ERROR_RATE, rng)
    events = Deframer().feed(stream)
    got = [(e.seq, e.message) for e in events if isinstance(e, Frame)]
    found, false_accepts = _recovered(sent, got, lambda s, r: s[0] % 256 == r[0] and s[1] == r[1])
    return len(damaged), n - len(found) - len(damaged - found), false_accepts


def _loss_mavlink(n: int, rng: random.Random) -> tuple[int, int, int]:
    mav = _mav()
    templates = [optical_flow(), control_system_state()]
    frames = [templates[i % 2].pack(mav) for i in range(n)]
    stream, damaged = _corrupt(frames, BYTE_ERROR_RATE, rng)
    parser = _mav()
    got = []
    for k in range(0, len(stream), 4096):  # as a serial reader would hand it over
        for msg in parser.parse_buffer(stream[k : k + 4096]) or []:
            # pymavlink reports bad CRCs as BAD_DATA and delivers frames whose (corrupted) message id it
            # does not know as UNKNOWN_<id> without a CRC check; an application drops both.
            if msg.get_type() != "BAD_DATA" and not msg.get_type().startswith("UNKNOWN_"):
                got.append(bytes(msg.get_msgbuf()))
    found, false_accepts = _recovered(frames, got, lambda s, r: s == r)
    return len(damaged), n - len(found) - len(damaged - found), false_accepts


def _loss_results(n: int) -> list[Result]:
    """Frames lost although not damaged, as a percentage of the damaged ones (DESIGN.md: MAVLink v2 ~13 %,
    COBS+CRC ~0)."""
    ours_damaged, ours_extra, ours_false = _loss_ours(n, random.Random(2024))
    theirs_damaged, theirs_extra, theirs_false = _loss_mavlink(n, random.Random(2024))
    ours = 100.0 * ours_extra / max(ours_damaged, 1)
    theirs = 100.0 * theirs_extra / max(theirs_damaged, 1)
    note = (
        f"{n} frames at {BYTE_ERROR_RATE:.0%} byte errors: ours {ours_damaged} damaged, {ours_extra} "
        f"undamaged lost, {ours_false} false accepts; MAVLink {theirs_damaged} damaged, {theirs_extra} "
        f"undamaged lost, "
        f"{theirs_false} false accepts (our extra losses are frames whose preceding delimiter was hit)"
    )
    return [
        Result(NAME, "undamaged frames lost at 1% byte errors", ours, "% of damaged", PEER, theirs,
               higher_is_better=False, note=note),
    ]  # fmt: skip


# =========================================================================== fuzzing speed
def _fuzz_results(runs: int) -> list[Result]:
    per_sec, inputs = fuzz_rate(FUZZ, runs, "vscmg-fuzz-")
    return [
        Result(NAME, "fuzz deframer+decode+CAN (atheris)", per_sec, "inputs/s",
               note=f"{inputs} inputs without an unhandled exception in this run; "
                    "python bench/fuzz_deframer.py -runs=1000000 for the full run"),
    ]  # fmt: skip


def run(quick: bool) -> list[Result]:
    min_time = 0.1 if quick else 1.0
    results = _codec_results("ActuatorSetpoint x4", setpoint(), optical_flow(), min_time)
    results += _codec_results("Telemetry x4/8ch", telemetry(), control_system_state(), min_time)
    results += _pure_decode_results("ActuatorSetpoint x4", setpoint(), optical_flow(), min_time)
    results += _pure_decode_results("Telemetry x4/8ch", telemetry(), control_system_state(), min_time)
    results += _cobs_results(telemetry(), min_time)
    results += _loss_results(2_000 if quick else 40_000)
    results += _fuzz_results(3_000 if quick else 100_000)
    return results
