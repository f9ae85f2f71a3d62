"""The MAX3421E model (``firmware/build/libmax3421e-model.so``) through ctypes, with a register-level host
written in Python: SPI commands as the datasheet frames them, and the few steps a USB host driver takes
(chip reset, bus reset, one transaction, a control transfer). The tests drive the model only through these
real SPI bytes and simulated microseconds, as the firmware does under simavr.
"""

from __future__ import annotations

import ctypes
import functools
import struct
import subprocess

from firmware_sim.avr.paths import BUILD_DIR, FIRMWARE_DIR

LIBRARY = BUILD_DIR / "libmax3421e-model.so"

# Register numbers (the command byte is reg << 3 | 2 for a write).
RCVFIFO, SNDFIFO, SUDFIFO, RCVBC, SNDBC = 1, 2, 4, 6, 7
USBIRQ, USBIEN, USBCTL, CPUCTL, PINCTL, REVISION = 13, 14, 15, 16, 17, 18
HIRQ, HIEN, MODE, PERADDR, HCTL, HXFR, HRSL = 25, 26, 27, 28, 29, 30, 31
# Bits.
OSCOKIRQ, CHIPRES, IE, FDUPSPI, INTLEVEL = 0x01, 0x20, 0x01, 0x10, 0x08
BUSEVENTIRQ, RCVDAVIRQ, SNDBAVIRQ, CONDETIRQ, FRAMEIRQ, HXFRDNIRQ = 0x01, 0x04, 0x08, 0x20, 0x40, 0x80
HOST, LOWSPEED, SOFKAENAB, DMPULLDN, DPPULLDN = 0x01, 0x02, 0x08, 0x40, 0x80
BUSRST, SAMPLEBUS, RCVTOG0, RCVTOG1, SNDTOG0, SNDTOG1 = 0x01, 0x04, 0x10, 0x20, 0x40, 0x80
RCVTOGRD, SNDTOGRD, KSTATUS, JSTATUS = 0x10, 0x20, 0x40, 0x80
# HXFR tokens and HRSL results.
TOK_SETUP, TOK_IN, TOK_OUT, TOK_HSIN, TOK_HSOUT = 0x10, 0x00, 0x20, 0x80, 0xA0
SUCCESS, BUSY, BADREQ, NAK, STALL, TOGERR, TIMEOUT = 0, 1, 2, 4, 5, 6, 14


@functools.cache
def library() -> ctypes.CDLL:
    """The model's host build, made first (only this target: the firmware may be mid-edit)."""
    subprocess.run(["make", "-C", str(FIRMWARE_DIR), "-s", "build/libmax3421e-model.so"], check=True)
    lib = ctypes.CDLL(str(LIBRARY))
    vp, u8, i, sz = ctypes.c_void_p, ctypes.c_uint8, ctypes.c_int, ctypes.c_size_t
    sig = {
        "max3421e_new": (vp, []),
        "max3421e_free": (None, [vp]),
        "max3421e_select": (None, [vp, i]),
        "max3421e_spi": (u8, [vp, u8]),
        "max3421e_int_asserted": (i, [vp]),
        "max3421e_reset_pin": (None, [vp, i]),
        "max3421e_advance": (None, [vp, ctypes.c_uint64]),
        "max3421e_phone_read": (sz, [vp, ctypes.c_char_p, sz]),
        "max3421e_phone_write": (sz, [vp, ctypes.c_char_p, sz]),
        "max3421e_phone_mode": (i, [vp]),
        "max3421e_phone_string": (ctypes.c_char_p, [vp, i]),
        "max3421e_fault": (i, [vp, ctypes.c_char_p, ctypes.c_double]),
        "max3421e_last_error": (ctypes.c_char_p, [vp]),
    }
    for name, (res, args) in sig.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


class UsbError(Exception):
    """A transaction ended with a result other than the one the host needed (HRSL code in ``code``)."""

    def __init__(self, what: str, code: int) -> None:
        super().__init__(f"{what}: HRSL result {code}")
        self.code = code


class Chip:
    """One model instance and a Python host driving it over SPI; ``now`` is simulated microseconds."""

    def __init__(self) -> None:
        self.lib = library()
        self.m = self.lib.max3421e_new()
        self.now = 0
        self.status = 0  # the HIRQ byte clocked out during the last command byte

    def close(self) -> None:
        if self.m:
            self.lib.max3421e_free(self.m)
            self.m = None

    # ------------------------------------------------------------------ SPI
    def command(self, reg: int, write: bool, data: bytes = b"", nread: int = 0) -> bytes:
        self.lib.max3421e_select(self.m, 1)
        self.status = self.lib.max3421e_spi(self.m, reg << 3 | (2 if write else 0))
        out = bytes(self.lib.max3421e_spi(self.m, b) for b in (data if write else bytes(nread)))
        self.lib.max3421e_select(self.m, 0)
        return out

    def wr(self, reg: int, value: int) -> None:
        self.command(reg, True, bytes([value]))

    def rd(self, reg: int) -> int:
        return self.command(reg, False, nread=1)[0]

    def wr_bytes(self, reg: int, data: bytes) -> None:
        self.command(reg, True, data)

    def rd_bytes(self, reg: int, n: int) -> bytes:
        return self.command(reg, False, nread=n)

    # ------------------------------------------------------------------ time
    def advance(self, us: int) -> None:
        self.now += us
        self.lib.max3421e_advance(self.m, self.now)

    def wait(self, reg: int, bit: int, timeout_us: int = 100_000, step_us: int = 2) -> int:
        """Poll ``reg`` until ``bit`` is set, moving time by ``step_us`` between polls; the microseconds
        waited. Raises TimeoutError past ``timeout_us``."""
        waited = 0
        while not self.rd(reg) & bit:
            if waited >= timeout_us:
                raise TimeoutError(f"register {reg} bit 0x{bit:02x} not set after {waited} us")
            self.advance(step_us)
            waited += step_us
        return waited

    # ------------------------------------------------------------------ host steps
    def start(self, reset_bus: bool = True) -> None:
        """Full-duplex SPI, chip reset, oscillator, host mode, SOFs and (by default) a bus reset."""
        self.wr(PINCTL, FDUPSPI | INTLEVEL)
        self.wr(USBCTL, CHIPRES)
        self.wr(USBCTL, 0)
        self.wait(USBIRQ, OSCOKIRQ, timeout_us=5000)
        self.wr(MODE, DPPULLDN | DMPULLDN | HOST | SOFKAENAB)
        if reset_bus:
            self.bus_reset()

    def bus_reset(self) -> None:
        self.wr(HIRQ, BUSEVENTIRQ)
        self.wr(HCTL, BUSRST)
        self.wait(HIRQ, BUSEVENTIRQ, timeout_us=60_000, step_us=500)
        self.wr(HIRQ, FRAMEIRQ)
        self.wait(HIRQ, FRAMEIRQ, timeout_us=2000, step_us=50)

    def xfer(self, token: int, ep: int = 0) -> int:
        """One transaction: launch, wait for HXFRDNIRQ, clear it; the HRSL result code."""
        self.wr(HXFR, token | ep)
        self.wait(HIRQ, HXFRDNIRQ, timeout_us=1000)
        self.wr(HIRQ, HXFRDNIRQ)
        return self.rd(HRSL) & 0x0F

    def xfer_retry(self, token: int, ep: int = 0, naks: int = 100) -> int:
        for _ in range(naks + 1):
            code = self.xfer(token, ep)
            if code != NAK:
                return code
        return NAK

    def receive(self, ep: int) -> bytes | None:
        """One IN packet into RCVFIFO (None on NAK); raises UsbError on anything else."""
        code = self.xfer(TOK_IN, ep)
        if code == NAK:
            return None
        if code != SUCCESS:
            raise UsbError(f"IN ep {ep}", code)
        assert self.rd(HIRQ) & RCVDAVIRQ
        n = self.rd(RCVBC)
        data = self.rd_bytes(RCVFIFO, n)
        self.wr(HIRQ, RCVDAVIRQ)
        return data

    def send(self, ep: int, data: bytes) -> int:
        """One OUT packet from SNDFIFO; the result code."""
        self.wr_bytes(SNDFIFO, data)
        self.wr(SNDBC, len(data))
        return self.xfer(TOK_OUT, ep)

    def setup(self, bm: int, req: int, value: int, index: int, length: int) -> None:
        self.wr_bytes(SUDFIFO, struct.pack("<BBHHH", bm, req, value, index, length))
        code = self.xfer(TOK_SETUP)
        if code != SUCCESS:
            raise UsbError("SETUP", code)

    def control_read(self, bm: int, req: int, value: int, index: int, length: int) -> bytes:
        self.setup(bm, req, value, index, length)
        self.wr(HCTL, RCVTOG1)
        data = b""
        while len(data) < length:
            code = self.xfer_retry(TOK_IN)
            if code != SUCCESS:
                raise UsbError("control read data", code)
            n = self.rd(RCVBC)
            data += self.rd_bytes(RCVFIFO, n)
            self.wr(HIRQ, RCVDAVIRQ)
            if n < 64:
                break
        code = self.xfer_retry(TOK_HSOUT)
        if code != SUCCESS:
            raise UsbError("control read status", code)
        return data

    def control_write(self, bm: int, req: int, value: int, index: int, data: bytes = b"") -> None:
        self.setup(bm, req, value, index, len(data))
        self.wr(HCTL, SNDTOG1)
        for k in range(0, len(data), 64):
            chunk = data[k : k + 64]
            self.wr_bytes(SNDFIFO, chunk)
            self.wr(SNDBC, len(chunk))
            code = self.xfer_retry(TOK_OUT)
            if code != SUCCESS:
                raise UsbError("control write data", code)
        code = self.xfer_retry(TOK_HSIN)
        if code != SUCCESS:
            raise UsbError("control write status", code)

    def enumerate(self, address: int = 1) -> bytes:
        """Device descriptor at address 0, SET_ADDRESS, configuration 1; the device descriptor."""
        self.wr(PERADDR, 0)
        desc = self.control_read(0x80, 6, 0x0100, 0, 18)
        self.control_write(0x00, 5, address, 0)
        self.wr(PERADDR, address)
        self.control_write(0x00, 9, 1, 0)
        return desc

    # ------------------------------------------------------------------ phone side
    def phone_write(self, data: bytes) -> int:
        return self.lib.max3421e_phone_write(self.m, data, len(data))

    def phone_read(self, cap: int = 8192) -> bytes:
        buf = ctypes.create_string_buffer(cap)
        n = self.lib.max3421e_phone_read(self.m, buf, cap)
        return buf.raw[:n]

    def mode(self) -> int:
        return self.lib.max3421e_phone_mode(self.m)

    def string(self, index: int) -> str:
        return self.lib.max3421e_phone_string(self.m, index).decode()

    def fault(self, name: str, value: float = 0) -> int:
        return self.lib.max3421e_fault(self.m, name.encode(), value)

    def last_error(self) -> str:
        return self.lib.max3421e_last_error(self.m).decode()

    def int_asserted(self) -> bool:
        return bool(self.lib.max3421e_int_asserted(self.m))
