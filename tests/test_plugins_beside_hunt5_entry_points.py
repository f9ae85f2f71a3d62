"""Plugins that are installed wrong beside ones installed right, through real dist-infos on ``sys.path``
(what pip leaves) and real ``hil`` processes, and plugin modules whose attributes raise as they are read.

Before: one installed package whose ``entry_points.txt`` had a line without ``=`` — in any group, its
``console_scripts`` too — ended every ``hil run``, the default demo included (its emulator is an entry
point), in a raw ``TypeError: Pair.__new__() missing 1 required positional argument``; one entry point of
``vscmg_hil.estimators`` whose value was no ``module:attribute`` made every estimator of the group a raw
``AttributeError: 'NoneType' object has no attribute 'group'``; a plugin module's ``__getattr__`` (a lazy
loader) or a kind's property that raised its own exception escaped ``hil run`` as a traceback."""

from __future__ import annotations

import builtins
import json
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main
from hil.estimation.registry import register_estimator
from hil.link import sources, transports
from hil.plugins import PASSES, Registry

REPO = Path(__file__).resolve().parents[1]


def _install(root: Path, dist: str, text: str) -> None:
    info = root / f"{dist}-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(text)


def _hil(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    path = [str(root), str(REPO)]  # this checkout's hil, whichever the environment installed
    script = f"import sys; sys.path[:0] = {path!r}; from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", script, *args], capture_output=True, text=True, timeout=180, cwd=root
    )


@pytest.fixture
def installed(tmp_path: Path) -> Path:
    (tmp_path / "good_hunt5_plug.py").write_text(
        "from hil.estimation.variational_kind import VARIATIONAL as KIND\n"
    )
    _install(tmp_path, "good_hunt5", "[vscmg_hil.estimators]\ngood = good_hunt5_plug:KIND\n")
    return tmp_path


def _summary(root: Path) -> dict:
    (run_dir,) = (root / "runs").iterdir()
    return json.loads((run_dir / "summary.json").read_text())


def test_a_package_whose_entry_points_cannot_be_read_is_passed_over_and_named(installed):
    _install(installed, "broken_hunt5", "[console_scripts]\njust a line without an equals sign\n")
    run = _hil(installed, "run", "--estimator", "good", "--duration", "1", "--no-plots", "--out", "runs")
    assert "Traceback" not in run.stderr, run.stderr
    assert run.returncode in (0, 1), run.stderr  # the emulator (an entry point) and the plugin found
    assert not _summary(installed)["exit"].startswith("error"), _summary(installed)["exit"]
    unknown = _hil(installed, "run", "--estimator", "nosuch", "--no-plots", "--out", "runs")
    assert unknown.returncode == 2 and "Traceback" not in unknown.stderr, unknown.stderr
    (line,) = [line for line in unknown.stderr.splitlines() if "nosuch" in line]
    assert "unknown estimator 'nosuch' (known: good, variational, vqf; entry points not read from: " in line
    assert "broken_hunt5 (TypeError: " in line


def test_an_entry_point_that_names_no_attribute_is_refused_alone_when_chosen(installed):
    _install(installed, "odd_hunt5", "[vscmg_hil.estimators]\nodd = not a valid target!!\n")
    run = _hil(installed, "run", "--estimator", "good", "--duration", "1", "--no-plots", "--out", "runs")
    assert run.returncode in (0, 1) and "Traceback" not in run.stderr, run.stderr
    odd = _hil(installed, "run", "--estimator", "odd", "--duration", "1", "--no-plots", "--out", "runs")
    assert odd.returncode == 2 and "Traceback" not in odd.stderr, odd.stderr
    assert "estimator 'odd' (not a valid target!!) is not available: 'not a valid target!!' is not " in (
        odd.stderr
    )


# --------------------------------------------------------------------------- attributes that raise
LAZY = "lazy_hunt5_plug"


@pytest.fixture
def lazy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    (tmp_path / f"{LAZY}.py").write_text(textwrap.dedent('''
        RAISES = RuntimeError

        def __getattr__(name):  # a lazy loader whose backend is missing
            raise RAISES(f"lazy attribute {name}: its backend is missing")

        class _Kind:
            @property
            def keys(self):
                raise RuntimeError("keys read from a file that is gone")

        KEYS_RAISE = _Kind()
    '''))  # fmt: skip
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, LAZY, raising=False)
    register_estimator("lazy-hunt5", f"{LAZY}:KIND")
    register_estimator("keys-hunt5", f"{LAZY}:KEYS_RAISE")
    transports.register("lazybus", f"{LAZY}:Bus")
    sources.register("lazyrig", f"{LAZY}:Rig")
    yield tmp_path
    sys.modules.pop(LAZY, None)


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--estimator", "lazy-hunt5"],
         "hil run: hil run --estimator: estimator 'lazy-hunt5' (lazy_hunt5_plug:KIND) is not available: "
         "reading lazy_hunt5_plug:KIND raised RuntimeError: lazy attribute KIND"),
        (["--estimator", "keys-hunt5"],
         "estimator 'keys-hunt5' (lazy_hunt5_plug:KEYS_RAISE) is not available: "
         "reading its kind raised RuntimeError: keys read from a file that is gone"),
        (["--port", "lazybus://x"],
         "hil run: lazybus://x: transport lazy_hunt5_plug:Bus is not available: "
         "reading lazy_hunt5_plug:Bus raised RuntimeError"),
        (["--port", "emu://", "--phone", "lazyrig://x"],
         "'lazyrig://x': phone source lazy_hunt5_plug:Rig is "
         "not available: reading lazy_hunt5_plug:Rig raised RuntimeError"),
    ],
)  # fmt: skip
def test_a_plugin_attribute_that_raises_as_it_is_read_is_one_line_naming_it(lazy, args, said, capsys):
    code = main(["run", *args, "--duration", "1", "--no-plots", "--out", str(lazy / "runs")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert said in err, err


EXCEPTIONS = [
    t for t in vars(builtins).values()
    if isinstance(t, type) and issubclass(t, BaseException) and not issubclass(t, PASSES)
    and t.__module__ == "builtins" and not t.__name__.endswith("Group")
    and not t.__name__.startswith("Unicode")  # their constructors take five arguments
]  # fmt: skip


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raises=st.sampled_from(EXCEPTIONS), attr=st.sampled_from(["KIND", "Holder.KIND", "a.b.c"]))
def test_loading_an_attribute_that_raises_anything_is_an_import_or_attribute_error(lazy, raises, attr):
    module = __import__(LAZY)
    module.RAISES = raises
    with pytest.raises((ImportError, AttributeError)) as refused:
        Registry.load(f"{LAZY}:{attr}")
    if not issubclass(raises, (ImportError, AttributeError)):
        assert str(refused.value).startswith(f"reading {LAZY}:{attr} raised {raises.__name__}"), refused.value
