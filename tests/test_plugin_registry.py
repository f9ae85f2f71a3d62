"""The plugin registry (``hil.plugins.Registry``) behind the estimators, transports and phone sources, fed
real installed entry points (a dist-info beside a module on ``sys.path``, exactly what pip leaves): a
plugin module that raises as it is imported (its own exception, a SyntaxError) is the registry's clear
error naming it, not a traceback; an entry point's dotted attribute and extras (valid entry-point syntax)
are loaded; one name given two targets by two packages (in two cases) is refused naming both, never
picked by ``sys.path`` order. Before, the first two were raw tracebacks, the third refused as "no
attribute 'Holder.KIND [fast]'", the last loaded whichever came first."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.plugins import Registry
from protocol.errors import RunHung

REPO = Path(__file__).resolve().parents[1]
LOG = REPO / "fixtures" / "logs" / "simulated_testbed_4s.csv"


def _install(root: Path, dist: str, group: str, entries: dict[str, str]) -> None:
    info = root / f"{dist}-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    lines = "".join(f"{name} = {value}\n" for name, value in entries.items())
    (info / "entry_points.txt").write_text(f"[{group}]\n{lines}")


@pytest.fixture
def installed(tmp_path: Path) -> Path:
    (tmp_path / "raises_plug.py").write_text('raise RuntimeError("plugin module fails at import")\n')
    (tmp_path / "syntax_plug.py").write_text("def f(:\n")
    (tmp_path / "good_plug.py").write_text(textwrap.dedent('''
        from hil.estimation.variational_kind import VARIATIONAL

        class Holder:
            KIND = VARIATIONAL
    '''))  # fmt: skip
    group = "vscmg_hil.estimators"
    _install(
        tmp_path,
        "plug_a",
        group,
        {
            "raises": "raises_plug:KIND",
            "syntax": "syntax_plug:KIND",
            "dotted": "good_plug:Holder.KIND",
            "extras": "good_plug:Holder.KIND [fast]",
            "Mine": "good_plug:Holder.KIND",
        },
    )
    _install(tmp_path, "plug_b", group, {"mine": "raises_plug:OTHER"})
    for g in ("vscmg_hil.transports", "vscmg_hil.phone_sources"):
        _install(tmp_path, f"plug_{g.rsplit('.', 1)[1]}", g, {"raising": "raises_plug:Factory"})
    return tmp_path


def _hil(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    path = [str(root), str(REPO)]  # this checkout's hil, whichever the environment installed
    script = f"import sys; sys.path[:0] = {path!r}; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", script, *args], capture_output=True, text=True, timeout=120, cwd=root
    )


@pytest.mark.parametrize(
    ("name", "said"),
    [
        ("raises", "estimator 'raises' (raises_plug:KIND) is not available: importing raises_plug raised "
         "RuntimeError: plugin module fails at import"),
        ("syntax", "importing syntax_plug raised SyntaxError: invalid syntax"),
        ("mine", "installed packages disagree on this name"),
    ],
)  # fmt: skip
def test_an_estimator_plugin_that_cannot_load_is_one_line_naming_it(installed, name, said, tmp_path):
    out = _hil(installed, "replay", str(LOG), "--estimator", name, "--no-plots", "--out", str(tmp_path / "o"))
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    assert said in out.stderr
    assert out.stderr.startswith("hil replay: error: --estimator: ")
    if name == "mine":  # both packages' targets named, whichever sys.path lists first
        assert "Mine = good_plug:Holder.KIND (plug_a)" in out.stderr
        assert "mine = raises_plug:OTHER (plug_b)" in out.stderr


@pytest.mark.parametrize("name", ["dotted", "extras"])
def test_an_entry_points_dotted_attribute_and_extras_are_loaded(installed, name, tmp_path):
    out = _hil(installed, "replay", str(LOG), "--estimator", name, "--no-plots", "--out", str(tmp_path / "o"))
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "o" / "summary.json").exists()


def test_a_transport_or_phone_source_module_that_raises_on_import_is_their_own_error(installed):
    script = textwrap.dedent(f'''
        import sys
        sys.path[:0] = {[str(installed), str(REPO)]!r}
        from hil.link.sources import create_source
        from hil.link.transports import create_transport
        from protocol.errors import ConfigError, TransportError
        try:
            create_transport("raising://x")
        except TransportError as exc:
            print("transport:", exc)
        try:
            create_source("raising://x", None)
        except ConfigError as exc:
            print("source:", exc)
    ''')  # fmt: skip
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("transport: raising://x: transport raises_plug:Factory is not available: ")
    assert lines[1].startswith("source: --phone: 'raising://x': phone source raises_plug:Factory is not")
    assert all("importing raises_plug raised RuntimeError: plugin module fails at import" in x for x in lines)


@settings(max_examples=200, deadline=None)
@given(st.text(st.sampled_from("ab_.:[], \t\n0é"), max_size=30))
def test_loading_any_target_is_an_import_or_attribute_error(text):
    """Whatever an entry point's value holds (no real module: a random one could run on import)."""
    with pytest.raises((ImportError, AttributeError)):
        Registry.load("zz_no_such_plugin" + text)
    with pytest.raises((ImportError, AttributeError)):
        Registry.load("good_plug_absent_" + text.replace(":", "") + ":" + text)


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, RunHung])
def test_an_interrupted_reading_of_the_entry_points_is_read_again_and_an_interrupt_is_never_the_plugins(
    installed, monkeypatch, interrupt
):
    """An interrupt (Ctrl-C, a campaign run's wall budget, raised wherever the run's thread is) that lands
    while the entry points are read: it passes, and the next use reads them again. Before: the registry
    was marked read first, and every later run of that campaign worker found no installed name ("unknown
    transport scheme 'emu'"). An interrupt landing in a plugin module's import passes as itself too, never
    made the plugin's ImportError."""
    import importlib.metadata

    monkeypatch.syspath_prepend(str(installed))
    real = importlib.metadata.entry_points
    calls = 0

    def interrupted(**kwargs):
        nonlocal calls
        calls += 1
        if calls == 1:
            raise interrupt
        return real(**kwargs)

    monkeypatch.setattr(importlib.metadata, "entry_points", interrupted)
    registry = Registry("vscmg_hil.estimators", {})
    with pytest.raises(interrupt):
        registry.names()
    assert "dotted" in registry.names() and calls == 2
    module = f"interrupted_by_{interrupt.__name__.lower()}"
    source = f"from protocol.errors import RunHung\nraise {interrupt.__name__}\n"
    (installed / f"{module}.py").write_text(source)
    with pytest.raises(interrupt):
        Registry.load(f"{module}:KIND")
