"""``python -m bench``: the JSON figures file, and a peer that is not installed (skipped with the command
that installs it, the other benchmarks still run)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FIELDS = {"bench", "name", "value", "unit", "peer", "peer_value", "ratio"}


def test_json_figures_and_a_missing_peer(tmp_path):
    """pymavlink shadowed by a module that is "not installed": the protocol benchmark is skipped with the
    pip command, the calibration benchmark runs, and its figures go to the JSON file and the table."""
    shadow = tmp_path / "site"
    shadow.mkdir()
    (shadow / "pymavlink.py").write_text(
        "raise ModuleNotFoundError(\"No module named 'pymavlink'\", name='pymavlink')\n"
    )
    out = tmp_path / "figures.json"
    done = subprocess.run(
        [sys.executable, "-m", "bench", "protocol", "calibration", "--quick", "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(shadow)},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    message = "[protocol]: its peer pymavlink is not installed: pip install -e '.[bench]'"
    assert f"skipped {message}" in done.stdout and message in done.stderr
    figures = json.loads(out.read_text())
    assert figures and all(set(f) == FIELDS for f in figures)
    assert {f["bench"] for f in figures} == {"calibration"}
    for f in figures:
        assert isinstance(f["value"], float) and f["name"] in done.stdout
        if f["peer_value"] is not None:  # ratio: ours against the peer, > 1 better
            assert f["peer"] and f["ratio"] is not None and f["ratio"] > 0
        else:
            assert f["ratio"] is None


def test_missing_peer_recognises_import_errors_and_helper_messages():
    from bench.__main__ import missing_peer

    assert missing_peer(ModuleNotFoundError("x", name="vqf.pyvqf")) == ("vqf", "bench")
    wrapped = RuntimeError("fuzz harness failed (exit 1): ModuleNotFoundError: No module named 'atheris'")
    assert missing_peer(wrapped) == ("atheris", "bench")
    assert missing_peer(ModuleNotFoundError("x", name="Basilisk.simulation")) == ("Basilisk", "basilisk")
    assert missing_peer(ModuleNotFoundError("x", name="numpy")) is None  # not a peer: a real failure
    assert missing_peer(ValueError("no module talk here")) is None
