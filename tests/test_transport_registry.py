"""The transport registry finds transports through entry points (the way python-can finds its
interfaces): firmware_sim registers the built-in emulator (``emu://``, ``spawn://``) so, and a third-party
package can add a scheme the same way; ``hil`` itself never imports ``firmware_sim``."""

import subprocess
import sys
import textwrap

from hil.link.transports import ENTRY_POINT_GROUP, InProcessBoard, create_transport, register, schemes
from hil.link.transports.base import Transport
from protocol.errors import TransportError


def test_the_emulator_schemes_come_from_firmware_sims_entry_points():
    import importlib.metadata

    points = {e.name: e.value for e in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}
    assert points["emu"] == "firmware_sim.servers.transports:EmulatorTransport"
    assert points["spawn"] == "firmware_sim.servers.transports:SpawnTransport"
    assert {"emu", "spawn", "can", "socket"} <= set(schemes())
    link = create_transport("emu://?units=3")
    assert isinstance(link, InProcessBoard) and type(link).__module__ == "firmware_sim.servers.transports"


def test_a_scheme_registered_at_run_time_is_used_and_an_unknown_one_is_named():
    class Echo(Transport):
        scheme = "echo"

        def _open_impl(self) -> None:
            self.buffer = b""

        def _read(self, timeout: float | None) -> bytes:
            out, self.buffer = self.buffer, b""
            return out

        def _write(self, data: bytes) -> None:
            self.buffer += data

        def _close(self) -> None:
            """Nothing to release: the bytes live in this object."""

    module = type(sys)("echo_transport_for_test")
    module.Echo = Echo  # type: ignore[attr-defined]
    sys.modules[module.__name__] = module
    try:
        register("echo", "echo_transport_for_test:Echo")
        with create_transport("echo://x").open() as link:
            link.write(b"ping")
            assert link.read(0) == b"ping"
    finally:
        del sys.modules[module.__name__]
    try:
        create_transport("nosuch://x")
    except TransportError as exc:
        assert "unknown transport scheme 'nosuch'" in str(exc) and "emu" in str(exc)
    else:
        raise AssertionError("an unknown scheme must be refused")


def test_a_third_party_package_registers_a_scheme_by_entry_point(tmp_path):
    """A package installed beside the project (here: a dist-info and a module on sys.path, exactly what
    pip leaves) adds ``loopback://`` without any change to hil."""
    (tmp_path / "thirdparty_link.py").write_text(textwrap.dedent('''
        from hil.link.transports.base import Transport

        class Loopback(Transport):
            def _open_impl(self):
                self.data = b""
            def _read(self, timeout):
                out, self.data = self.data, b""
                return out
            def _write(self, data):
                self.data += data
            def _close(self):
                self.data = b""  # nothing else to release: the bytes live in this object
    '''))  # fmt: skip
    info = tmp_path / "thirdparty_link-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-link\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nloopback = thirdparty_link:Loopback\n")
    script = textwrap.dedent(f'''
        import sys
        sys.path.insert(0, {str(tmp_path)!r})
        from hil.link.transports import create_transport, schemes
        assert "loopback" in schemes(), schemes()
        with create_transport("loopback://here").open() as link:
            link.write(b"abc")
            print(type(link.inner).__module__, link.read(0).decode())  # held to its interface
    ''')  # fmt: skip
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["thirdparty_link", "abc"]


def test_hil_never_imports_firmware_sim():
    """Every hil module imported, and not one firmware_sim module with them (the import-linter contract
    checks the source; this checks what actually loads)."""
    script = textwrap.dedent('''
        import importlib, pkgutil, sys
        import hil
        for m in pkgutil.walk_packages(hil.__path__, "hil."):
            if m.name != "hil.__main__":
                importlib.import_module(m.name)
        loaded = sorted(n for n in sys.modules if n.split(".")[0] == "firmware_sim")
        print(len([n for n in sys.modules if n.startswith("hil.")]), loaded)
    ''')  # fmt: skip
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    count, loaded = out.stdout.split(" ", 1)
    assert int(count) > 60 and loaded.strip() == "[]"
