"""The firmware's portable C modules on the host (``firmware/build/libfirmware-host.so``) through ctypes.

The codec (deframer, frame encoder, wire tables), the calibration maps, the power manager, the state
machine, the answer cache, the calibration reassembler and the configuration parser are compiled for the
host from the same sources as the board firmware, so the tests can run them against the Python reference
on thousands of generated cases (the AVR itself runs them on the protocol test vectors). Floats are
float32 on both: the host build computes what the ATmega computes.
"""

from __future__ import annotations

import ctypes
import functools
import struct
from dataclasses import dataclass

from protocol.frame import BadFrameReason

from .build import ensure_built
from .paths import BUILD_DIR

LIBRARY = BUILD_DIR / "libfirmware-host.so"
REASONS = tuple(BadFrameReason)  # C reason codes are 1 + the index here (codegen: BAD_FRAME_*)
_U8P = ctypes.POINTER(ctypes.c_uint8)
_FEED_CHUNK = 4096


class CalConversion(ctypes.Structure):
    _fields_ = [("value", ctypes.c_float), ("clamp", ctypes.c_uint8)]


class PowerParams(ctypes.Structure):
    _fields_ = [
        ("warn_v_cell", ctypes.c_float),
        ("limit_v_cell", ctypes.c_float),
        ("shed_v_cell", ctypes.c_float),
        ("hysteresis_v_cell", ctypes.c_float),
        ("alpha", ctypes.c_float),
        ("cells", ctypes.c_uint8),
    ]


class PowerManagerState(ctypes.Structure):
    _fields_ = [("filtered_v_cell", ctypes.c_float), ("primed", ctypes.c_uint8), ("stage", ctypes.c_uint8)]


class Transition(ctypes.Structure):
    _fields_ = [("state", ctypes.c_uint8), ("refused", ctypes.c_uint8)]


@functools.cache
def library() -> ctypes.CDLL:
    """The host library, built first if needed."""
    ensure_built()
    lib = ctypes.CDLL(str(LIBRARY))
    sig = {
        "host_deframer_new": (ctypes.c_void_p, []),
        "host_deframer_free": (None, [ctypes.c_void_p]),
        "host_deframer_reset": (None, [ctypes.c_void_p]),
        "host_deframer_feed": (
            ctypes.c_long,
            [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_uint32, _U8P, ctypes.c_uint32],
        ),
        "host_deframer_counters": (None, [ctypes.c_void_p, ctypes.POINTER(ctypes.c_uint32)]),
        "host_reasm_new": (ctypes.c_void_p, [ctypes.c_uint16]),
        "host_reasm_feed": (
            ctypes.c_int,
            [ctypes.c_void_p]
            + [ctypes.c_uint8] * 4
            + [ctypes.c_uint16] * 2
            + [ctypes.c_char_p, ctypes.c_uint8],
        ),
        "host_reasm_buf": (_U8P, [ctypes.c_void_p]),
        "host_answers_new": (ctypes.c_void_p, []),
        "host_answers_lookup": (
            ctypes.c_int,
            [ctypes.c_void_p] + [ctypes.c_uint8] * 3 + [ctypes.c_char_p, ctypes.c_uint8],
        ),
        "host_answers_remember": (
            None,
            [ctypes.c_void_p] + [ctypes.c_uint8] * 2 + [ctypes.c_char_p] + [ctypes.c_uint8] * 2,
        ),
        "host_config_parse": (
            ctypes.c_int,
            [ctypes.c_char_p, ctypes.POINTER(ctypes.c_float), ctypes.c_char_p, _U8P],
        ),
        "cal_validate": (ctypes.c_int, [ctypes.c_char_p, ctypes.c_uint16, _U8P, _U8P]),
        "cal_rotor_pulse_us": (CalConversion, [ctypes.c_char_p, ctypes.c_float, ctypes.c_float]),
        "cal_rotor_speed": (CalConversion, [ctypes.c_char_p, ctypes.c_float, ctypes.c_float]),
        "cal_gimbal_pulse_us": (CalConversion, [ctypes.c_char_p, ctypes.c_float, ctypes.c_uint8]),
        "cal_gimbal_value": (CalConversion, [ctypes.c_char_p, ctypes.c_float, ctypes.c_uint8]),
        "cal_status_text": (None, [ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]),
        "power_reset": (None, [ctypes.POINTER(PowerManagerState)]),
        "power_update": (
            ctypes.c_uint8,
            [ctypes.POINTER(PowerManagerState), ctypes.POINTER(PowerParams), ctypes.c_float],
        ),
        "power_soc": (ctypes.c_float, [ctypes.c_float]),
        "state_transition": (Transition, [ctypes.c_uint8] * 3),
        "crc16_update": (ctypes.c_uint16, [ctypes.c_uint16, ctypes.c_char_p, ctypes.c_uint16]),
        "cobs_encode": (ctypes.c_uint16, [ctypes.c_char_p, ctypes.c_uint16, _U8P]),
        "cobs_decode_in_place": (ctypes.c_int16, [_U8P, ctypes.c_uint16]),
    }
    for name, (restype, argtypes) in sig.items():
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes
    return lib


# --------------------------------------------------------------------------- codec
@dataclass(frozen=True)
class CFrame:
    """A frame the C deframer accepted: header fields and the frame re-encoded from its decoded message."""

    msg_id: int
    seq: int
    flags: int
    wire: bytes


class CDeframer:
    """The firmware's deframer: ``feed(bytes)`` returns :class:`CFrame` or :class:`BadFrameReason` events."""

    def __init__(self) -> None:
        self._lib = library()
        self._h = self._lib.host_deframer_new()

    def __del__(self) -> None:
        h, self._h = getattr(self, "_h", None), None
        if h:
            self._lib.host_deframer_free(h)

    def feed(self, data: bytes) -> list[CFrame | BadFrameReason]:
        events: list[CFrame | BadFrameReason] = []
        data = bytes(data)
        for start in range(0, len(data), _FEED_CHUNK):
            events += self._feed(data[start : start + _FEED_CHUNK])
        return events

    def _feed(self, data: bytes) -> list[CFrame | BadFrameReason]:
        # a frame event (<= 265 bytes) needs at least 7 input bytes, a bad one (2 bytes) at least 1
        cap = 2 * len(data) + 265 * (len(data) // 7 + 1)
        out = (ctypes.c_uint8 * cap)()
        n = self._lib.host_deframer_feed(self._h, data, len(data), out, cap)
        if n < 0:
            raise RuntimeError("host_deframer_feed: output buffer too small")
        raw = bytes(out[:n])
        events: list[CFrame | BadFrameReason] = []
        i = 0
        while i < n:
            if raw[i] == 1:
                length = struct.unpack_from("<H", raw, i + 4)[0]
                events.append(CFrame(raw[i + 1], raw[i + 2], raw[i + 3], raw[i + 6 : i + 6 + length]))
                i += 6 + length
            else:
                events.append(REASONS[raw[i + 1] - 1])
                i += 2
        return events

    def reset(self) -> None:
        self._lib.host_deframer_reset(self._h)

    def counters(self) -> dict[str, object]:
        out = (ctypes.c_uint32 * (6 + len(REASONS)))()
        self._lib.host_deframer_counters(self._h, out)
        names = ("frames", "bad_total", "resyncs", "seq_gaps", "duplicates", "bytes")
        result: dict[str, object] = dict(zip(names, out[:6], strict=True))
        result["bad"] = {r: out[6 + i] for i, r in enumerate(REASONS) if out[6 + i]}
        return result


def crc16(data: bytes, value: int = 0xFFFF) -> int:
    return int(library().crc16_update(value, bytes(data), len(data)))


def cobs_encode(data: bytes) -> bytes:
    out = (ctypes.c_uint8 * (len(data) + len(data) // 254 + 2))()
    n = library().cobs_encode(bytes(data), len(data), out)
    return bytes(out[:n])


def cobs_decode(data: bytes) -> bytes | None:
    buf = (ctypes.c_uint8 * max(len(data), 1)).from_buffer_copy(bytes(data) or b"\0")
    n = library().cobs_decode_in_place(buf, len(data))
    return None if n < 0 else bytes(buf[:n])


# --------------------------------------------------------------------------- calibration
def cal_validate(data: bytes) -> tuple[int, int, int]:
    """(status, table, knot) of the C validation (status 0: accepted)."""
    table, knot = ctypes.c_uint8(), ctypes.c_uint8()
    status = library().cal_validate(bytes(data), len(data), ctypes.byref(table), ctypes.byref(knot))
    return int(status), table.value, knot.value


def cal_status_text(status: int) -> str:
    buf = ctypes.create_string_buffer(80)
    library().cal_status_text(status, buf, len(buf))
    return buf.value.decode()


def cal_call(name: str, data: bytes, x: float, arg: float | int) -> tuple[float, int]:
    """(value, clamp) of ``cal_<name>(set, x, arg)``."""
    r = getattr(library(), f"cal_{name}")(bytes(data), x, arg)
    return float(r.value), int(r.clamp)


# --------------------------------------------------------------------------- small state machines
class CPowerManager:
    def __init__(
        self, warn: float, limit: float, shed: float, hysteresis: float, alpha: float, cells: int
    ) -> None:
        self.params = PowerParams(warn, limit, shed, hysteresis, alpha, cells)
        self.state = PowerManagerState()
        library().power_reset(ctypes.byref(self.state))

    def update(self, battery_v: float) -> int:
        return int(library().power_update(ctypes.byref(self.state), ctypes.byref(self.params), battery_v))


def state_transition(state: int, event: int, power_ok: bool) -> tuple[int, int]:
    t = library().state_transition(state, event, int(power_ok))
    return int(t.state), int(t.refused)


class CReassembler:
    def __init__(self, max_len: int) -> None:
        self._lib = library()
        self._h = self._lib.host_reasm_new(max_len)

    def feed(
        self, unit: int, transfer_id: int, index: int, count: int, total_len: int, set_crc: int, chunk: bytes
    ) -> int:
        return int(
            self._lib.host_reasm_feed(
                self._h, unit, transfer_id, index, count, total_len, set_crc, bytes(chunk), len(chunk)
            )
        )

    def data(self, n: int) -> bytes:
        return ctypes.string_at(self._lib.host_reasm_buf(self._h), n)


class CAnswerCache:
    def __init__(self) -> None:
        self._lib = library()
        self._h = self._lib.host_answers_new()

    def lookup(self, msg_id: int, seq: int, flags: int, payload: bytes) -> int | None:
        r = self._lib.host_answers_lookup(self._h, msg_id, seq, flags, bytes(payload), len(payload))
        return None if r < 0 else int(r)

    def remember(self, msg_id: int, seq: int, payload: bytes, answer: int) -> None:
        self._lib.host_answers_remember(self._h, msg_id, seq, bytes(payload), len(payload), answer)


CONFIG_NUMBERS = (
    "n_units",
    "frame_rate_hz",
    "telemetry_rate_hz",
    "heartbeat_rate_hz",
    "link_timeout_ms",
    "mcu_watchdog_ms",
    "rotor_safe_us",
    "ppm",
    "cells",
    "warn_v_cell",
    "limit_v_cell",
    "shed_v_cell",
    "baud",
    "esc_supply_switch",
    "link",
)


def config_parse(block: bytes) -> tuple[int, dict[str, float | str], int]:
    """(status, fields, problem) of the firmware's configuration parser (status 0: loaded)."""
    numbers = (ctypes.c_float * len(CONFIG_NUMBERS))()
    serial = ctypes.create_string_buffer(32)
    problem = ctypes.c_uint8()
    status = library().host_config_parse(bytes(block), numbers, serial, ctypes.byref(problem))
    fields: dict[str, float | str] = dict(zip(CONFIG_NUMBERS, numbers, strict=True))
    fields["serial"] = serial.value.decode()
    return int(status), fields, problem.value
