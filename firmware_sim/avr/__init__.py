"""The board's real firmware (``firmware/``, C for the ATmega2560) run on simavr behind a pseudo-terminal.

* :class:`AvrBoard` — the firmware ELF on an emulated ATmega2560 (the ``avr-harness`` process), with the
  conformance ``Target`` operations: harness time, pulse timeline, resets, fault injection.
* :func:`ensure_built` — ``make -C firmware`` (firmware, codec check, harness, host library).
* :mod:`.codegen` — generates the firmware's protocol and board headers from the Python sources
  (the board header in :mod:`.codegen_board`, C literals in :mod:`.c_literals`).
* :mod:`.eeprom` — the EEPROM image (board configuration block, calibration slots).
* :mod:`.records` — the harness's record of pulse edges and resets as frames.
* :mod:`.hostlib` — the firmware's portable C modules on the host through ctypes (tests).

``firmware-sim --avr`` serves the firmware on a pty like ``firmware-sim`` serves the Python emulator.
"""

from .build import ToolchainMissing, ensure_built, missing_tools
from .harness import AvrBoard, HarnessOptions
from .paths import CODEC_CHECK_ELF, FIRMWARE_DIR, FIRMWARE_ELF

__all__ = [
    "CODEC_CHECK_ELF",
    "FIRMWARE_DIR",
    "FIRMWARE_ELF",
    "AvrBoard",
    "HarnessOptions",
    "ToolchainMissing",
    "ensure_built",
    "missing_tools",
]
