"""The firmware's generated definitions stay in step with the Python sources of truth, and the build
meets its budgets (flash, RAM, warnings as errors)."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from firmware_sim.avr import codegen, ensure_built
from firmware_sim.avr.paths import BUILD_DIR, FIRMWARE_DIR, FIRMWARE_ELF
from protocol.messages import CATALOGUE, SCHEMA_HASH


def test_committed_generated_files_are_not_stale():
    assert codegen.stale_files() == [], "run: python -m firmware_sim.avr.codegen"


def test_the_check_fails_on_a_drifted_header(tmp_path, monkeypatch):
    drifted = tmp_path / "protocol_gen.h"
    drifted.write_text(codegen.HEADER_PATH.read_text().replace(f"{SCHEMA_HASH:#010x}", "0xdeadbeef"))
    monkeypatch.setattr(codegen, "HEADER_PATH", drifted)
    assert codegen.stale_files() == [drifted]


def test_check_command_line():
    result = subprocess.run(
        [sys.executable, "-m", "firmware_sim.avr.codegen", "--check"], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr
    assert (
        "--check"
        in subprocess.run(
            [sys.executable, "-m", "firmware_sim.avr.codegen", "--help"], capture_output=True, text=True
        ).stdout
    )


def test_every_message_has_an_id_a_struct_and_a_layout():
    header = codegen.HEADER_PATH.read_text()
    source = codegen.SOURCE_PATH.read_text()
    for cls in CATALOGUE:
        name = codegen.snake(cls.__name__)
        assert f"#define MSG_{name.upper()} {cls.MSG_ID:#04x}u" in header
        assert f"}} {name}_t;" in header
        assert f"const wire_layout_t WIRE_LAYOUT_{name.upper()}" in source
    assert f"#define SCHEMA_HASH {SCHEMA_HASH:#010x}UL" in header


def _size_report() -> dict[str, int]:
    ensure_built()
    out = subprocess.run(
        ["avr-size", "-A", str(FIRMWARE_ELF)], capture_output=True, text=True, check=True
    ).stdout
    sizes = {m[2]: int(m[3]) for m in re.finditer(r"^(\.(\w+))\s+(\d+)", out, re.M)}
    return {k: sizes.get(k, 0) for k in ("text", "data", "bss", "noinit")}


@pytest.mark.firmware
def test_the_firmware_fits_the_atmega2560_with_room_for_its_stack():
    s = _size_report()
    assert s["text"] + s["data"] < 256 * 1024 - 8 * 1024  # flash, leaving the bootloader's 8 KB
    ram = s["data"] + s["bss"] + s["noinit"]
    assert ram <= 8192 - 1024, f"{ram} bytes of RAM in variables leave under 1 KB for the stack"


@pytest.mark.firmware
def test_warnings_are_errors_in_every_build():
    makefile = (FIRMWARE_DIR / "Makefile").read_text()
    assert makefile.count("-Werror") >= 2  # the AVR flags and the host flags
    assert (BUILD_DIR / "vscmg-adk.hex").exists() and (BUILD_DIR / "codec-check.elf").exists()


@pytest.mark.firmware
@pytest.mark.parametrize("broken", ["int unused_but_set(void) { int x = 1; x++; return 0; }"])
def test_a_warning_breaks_the_avr_build(tmp_path, broken):
    src = tmp_path / "warn.c"
    src.write_text(broken + "\n")
    result = subprocess.run(
        [
            "make",
            "-s",
            "-C",
            str(FIRMWARE_DIR),
            "-f",
            "Makefile",
            "--eval",
            f"probe: ; $(AVRCC) $(AVRFLAGS) -Wmissing-prototypes -c {src} -o {tmp_path / 'warn.o'}",
            "probe",
        ],
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0 and "error" in result.stderr
