"""Where the firmware's sources and build outputs live (the checkout is installed in editable mode)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE_DIR = ROOT / "firmware"
APT_PACKAGES = ROOT / ".ci" / "apt-packages"
"""The one list of Debian packages the firmware build and its tests need."""
BUILD_DIR = FIRMWARE_DIR / "build"
FIRMWARE_ELF = BUILD_DIR / "vscmg-adk.elf"
"""The board firmware: the very binary that is flashed (its .hex beside it)."""
CODEC_CHECK_ELF = BUILD_DIR / "codec-check.elf"
"""The firmware's codec alone, echoing decoded frames (for the protocol test vectors)."""
HARNESS = BUILD_DIR / "avr-harness"
"""The host program that runs an ELF on simavr behind a pseudo-terminal."""
