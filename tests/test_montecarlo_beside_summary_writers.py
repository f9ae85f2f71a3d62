"""Two writers of one summary.json at once: ``hil report DIR`` while the session writing DIR ends, or two
reports. Both write through :func:`hil.runtime.runlog.write_summary`, which used one fixed temporary,
``summary.json.tmp``: one writer renamed the other's half-written file into place (~3 % of concurrent reads
saw invalid JSON) and the other's rename then failed ("No such file or directory", ~3 % of writes). Now each
writer has its own temporary: every read is one writer's whole document, no write fails, none is left."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from hil.runtime.runlog import SUMMARY, write_summary

_WRITER = """
import sys, time
from hil.runtime.runlog import write_summary
out, who, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
doc = {"writer": who, "runs": list(range(20000))}  # ~140 kB: a write takes a while
n = failed = 0
end = time.monotonic() + seconds
while time.monotonic() < end:
    try:
        write_summary(out, doc)
        n += 1
    except Exception as exc:
        failed += 1
        print(type(exc).__name__, exc, file=sys.stderr)
print(n, failed)
"""


def test_two_processes_writing_summary_json_never_show_a_reader_half_a_file(tmp_path):
    out = tmp_path / "mc"
    out.mkdir()
    write_summary(out, {"writer": "first", "runs": []})
    root = Path(__file__).resolve().parents[1]
    writers = [
        subprocess.Popen(
            [sys.executable, "-c", _WRITER, str(out), who, "3"],
            cwd=root,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for who in ("a", "b")
    ]
    reads = torn = 0
    seen = set()
    end = time.monotonic() + 4.0
    while time.monotonic() < end and any(w.poll() is None for w in writers):
        text = (out / SUMMARY).read_text()  # always there: every write is a rename over it
        reads += 1
        try:
            seen.add(json.loads(text)["writer"])
        except ValueError:
            torn += 1
    said = [w.communicate(timeout=30) for w in writers]
    for (stdout, stderr), w in zip(said, writers, strict=True):
        assert w.returncode == 0, stderr[-2000:]
        written, failed = map(int, stdout.split())
        assert written > 0 and failed == 0, stderr[-2000:]
    assert reads > 0 and torn == 0, f"{torn} of {reads} reads saw half a file"
    assert seen <= {"first", "a", "b"}
    assert sorted(p.name for p in out.iterdir()) == [SUMMARY]  # no temporary left behind
    assert json.loads((out / SUMMARY).read_text())["writer"] in ("a", "b")


def test_summary_json_is_readable_as_any_file_hil_writes(tmp_path):
    """mkstemp makes its file 0600: renamed into place, summary.json would have become unreadable to the
    group and others, which a plain write gave it (under the usual umask 022)."""
    import os

    old = os.umask(0o022)
    try:
        path = write_summary(tmp_path, {"runs": 1})
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644
