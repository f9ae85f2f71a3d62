"""Building the firmware, its codec check and the simavr harness with ``make -C firmware``.

The toolchain is Debian's (gcc-avr, avr-libc, binutils-avr for the firmware; gcc, libsimavr-dev,
libelf-dev, pkg-config for the harness; ``.ci/apt-packages`` lists them). A missing tool is a
:class:`ConfigError` that says what to install: the tests that need the firmware then fail loudly, they
never skip.
"""

from __future__ import annotations

import shutil
import subprocess
import threading

from protocol.errors import ConfigError

from .paths import FIRMWARE_DIR

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

_lock = threading.Lock()
_built = False


def missing_tools() -> list[str]:
    """Debian packages whose tools or headers are missing (empty when the build can run)."""
    from pathlib import Path

    missing = {pkg for tool, pkg in TOOLS.items() if shutil.which(tool) is None}
    missing |= {pkg for path, pkg in HEADERS.items() if not Path(path).exists()}
    return sorted(missing)


def ensure_built(force: bool = False) -> None:
    """Run ``make -C firmware`` once per process (make itself skips what is up to date)."""
    global _built
    with _lock:
        if _built and not force:
            return
        missing = missing_tools()
        if missing:
            raise ConfigError(
                f"cannot build the firmware: install the Debian packages {', '.join(missing)}"
                " (see .ci/apt-packages)",
                "firmware/Makefile",
            )
        result = subprocess.run(
            ["make", "-C", str(FIRMWARE_DIR), "all"], capture_output=True, text=True, check=False
        )
        if result.returncode != 0:
            tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-30:])
            raise ConfigError(f"make failed (exit {result.returncode}):\n{tail}", "firmware/Makefile")
        _built = True
