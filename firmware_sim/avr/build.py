"""Building the firmware, its codec check and the simavr harness with ``make -C firmware``.

The toolchain is Debian's (gcc-avr, avr-libc, binutils-avr for the firmware; gcc, libsimavr-dev,
libelf-dev, pkg-config for the harness). ``.ci/apt-packages`` is the one list of them: ``.ci/run``
installs it, the README points to it and :class:`ToolchainMissing` quotes it. A missing tool is a
:class:`ToolchainMissing` that says what to install; the tests that need the firmware are marked
``firmware`` and skip with one line naming the packages (``tests/conftest.py``), unless
``VSCMG_HIL_REQUIRE_ALL=1`` (set by ``.ci/run``) makes the absence a failure.
"""

from __future__ import annotations

import shutil
import subprocess
import threading

from protocol.errors import ConfigError

from .paths import APT_PACKAGES, FIRMWARE_DIR

TOOLS = {
    "make": "make",
    "avr-gcc": "gcc-avr",
    "avr-objcopy": "binutils-avr",
    "avr-size": "binutils-avr",
    "cc": "gcc",
    "pkg-config": "pkg-config",
}
HEADERS = {
    "/usr/include/simavr/sim_avr.h": "libsimavr-dev",
    "/usr/include/libelf.h": "libelf-dev",
    "/usr/lib/avr/include/avr/io.h": "avr-libc",
}


class ToolchainMissing(ConfigError):
    """The AVR toolchain or simavr is not installed: the firmware cannot be built (names the packages)."""


def apt_packages() -> list[str]:
    """The Debian packages of ``.ci/apt-packages`` (the one list), or those the checks below name when
    the checkout's ``.ci`` folder is not there (an installed, not editable, package)."""
    try:
        lines = APT_PACKAGES.read_text(encoding="utf-8").splitlines()
    except OSError:
        return sorted(set(TOOLS.values()) | set(HEADERS.values()))
    return [w for line in lines for w in line.split("#", 1)[0].split()]


def install_hint() -> str:
    """Which packages to install, and how."""
    return (
        f"install the Debian packages of .ci/apt-packages ({' '.join(apt_packages())}): "
        "sudo apt-get install $(grep -v '^#' .ci/apt-packages)"
    )


_lock = threading.Lock()
_built = False


def missing_tools() -> list[str]:
    """Debian packages whose tools or headers are missing (empty when the build can run)."""
    from pathlib import Path

    missing = {pkg for tool, pkg in TOOLS.items() if shutil.which(tool) is None}
    missing |= {pkg for path, pkg in HEADERS.items() if not Path(path).exists()}
    return sorted(missing)


def toolchain_message(missing: list[str]) -> str:
    """What a user without the toolchain reads (the skip line of the tests, ``firmware-sim --avr``)."""
    return f"the board firmware cannot be built ({', '.join(missing)} missing); {install_hint()}"


def ensure_built(force: bool = False) -> None:
    """Run ``make -C firmware`` once per process (make itself skips what is up to date)."""
    global _built
    with _lock:
        if _built and not force:
            return
        missing = missing_tools()
        if missing:
            raise ToolchainMissing(toolchain_message(missing), "firmware/Makefile")
        result = subprocess.run(
            ["make", "-C", str(FIRMWARE_DIR), "all"], capture_output=True, text=True, check=False
        )
        if result.returncode != 0:
            tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-30:])
            raise ConfigError(f"make failed (exit {result.returncode}):\n{tail}", "firmware/Makefile")
        _built = True
