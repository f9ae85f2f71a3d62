"""Run directories: incremental, flushed logs that survive SIGKILL; torn lines are counted, not fatal."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from hil.runtime.runlog import (
    CsvLog,
    EventLog,
    new_run_dir,
    read_events,
    read_telemetry,
    write_summary,
)
from protocol.errors import InputFormatError

WRITER = """
import sys, time
from hil.runtime.runlog import CsvLog, EventLog
log = CsvLog(sys.argv[1] + "/telemetry.csv", ["t", "angle_deg"])
ev = EventLog(sys.argv[1] + "/events.jsonl")
i = 0
while True:
    log.write({"t": i * 0.01, "angle_deg": 90.0 - i})
    if i % 10 == 0:
        ev.write(i * 0.01, "tick", n=i)
    if i == 50:
        print("ready", flush=True)
    i += 1
    time.sleep(0.001)
"""


def _lines_on_disk(path) -> int:
    return path.read_bytes().count(b"\n") if path.exists() else 0


def test_a_sigkilled_writer_leaves_a_readable_log(tmp_path):
    """SIGKILL while rows and events are being written: every row that had reached the file is read back,
    in order, at most one torn line dropped. The kill comes once the writer thread has put row 50 in the
    file (waited for, not timed: a CI machine running two passes once took longer than a fixed 50 ms)."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    telemetry = tmp_path / "telemetry.csv"
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 30.0
        while _lines_on_disk(telemetry) < 52 and time.monotonic() < deadline:  # the header and 51 rows
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    tel = read_telemetry(telemetry)
    assert tel.rows >= 51 and tel.dropped_lines <= 1
    n = tel.rows
    assert list(tel["angle_deg"][:n]) == [90.0 - i for i in range(n)]
    events, torn = read_events(tmp_path / "events.jsonl")
    assert torn <= 1 and [e["n"] for e in events] == list(range(0, 10 * len(events), 10))


def test_torn_and_malformed_lines_are_dropped_and_counted(tmp_path):
    path = tmp_path / "telemetry.csv"
    path.write_text("t,x\n0.0,1.0\n0.1,\n0.2,abc\n0.3,4.0\n0.4")
    tel = read_telemetry(path)
    assert tel.rows == 3 and tel.dropped_lines == 2
    assert math.isnan(tel["x"][1]) and tel["x"][2] == 4.0


def test_missing_or_empty_telemetry_names_the_file(tmp_path):
    with pytest.raises(InputFormatError, match="nothing.csv"):
        read_telemetry(tmp_path / "nothing.csv")
    (tmp_path / "empty.csv").write_text("")
    with pytest.raises(InputFormatError, match="empty.csv:1"):
        read_telemetry(tmp_path / "empty.csv")


def test_rows_with_unknown_columns_are_refused_and_none_is_empty(tmp_path):
    with CsvLog(tmp_path / "t.csv", ["t", "a"]) as log:
        log.write({"t": 1.0})
        with pytest.raises(KeyError, match="typo"):
            log.write({"t": 2.0, "typo": 3.0})
    tel = read_telemetry(tmp_path / "t.csv")
    assert tel.rows == 1 and math.isnan(tel["a"][0])
    with pytest.raises(ValueError):
        CsvLog(tmp_path / "u.csv", ["t", "t"])


def test_summary_is_atomic_json_and_run_dirs_never_collide(tmp_path):
    a = new_run_dir(tmp_path, "slew 90°")
    b = new_run_dir(tmp_path, "slew 90°")
    assert a != b and a.is_dir() and b.is_dir() and "/" not in a.name
    import numpy as np

    write_summary(a, {"settle_s": np.float64(12.5), "path": a, "arr": np.arange(3)})
    data = json.loads((a / "summary.json").read_text())
    assert data == {"settle_s": 12.5, "path": str(a), "arr": [0, 1, 2]}
    assert not list(a.glob("*.tmp"))
    ev = EventLog(a / "events.jsonl")
    ev.write(0.5, "state", old="DISARMED", new="ARMED")
    ev.close()
    with pytest.raises(ValueError):
        ev.write(1.0, "late")
    events, torn = read_events(a / "events.jsonl")
    assert events == [{"t": 0.5, "kind": "state", "old": "DISARMED", "new": "ARMED"}] and torn == 0


def test_numpy_scalars_are_written_as_plain_numbers(tmp_path):
    path = tmp_path / "t.csv"
    with CsvLog(path, ["t", "b", "c", "d"]) as log:
        log.write({"t": np.float64(0.125), "b": np.int64(7), "c": np.float32(np.nan), "d": np.bool_(True)})
    assert path.read_text().splitlines()[1] == "0.125,7,,1"
    tel = read_telemetry(path)
    assert tel.rows == 1 and tel.dropped_lines == 0 and tel["b"][0] == 7.0


def test_a_small_queue_slows_the_writer_down_but_loses_no_row(tmp_path):
    path = tmp_path / "t.csv"
    with CsvLog(path, ["t", "x"], max_pending=4, batch_s=0.001) as log:
        for i in range(2000):
            log.write_values([i, i * 0.5])
        log.flush()
        assert read_telemetry(path).rows == 2000  # flush(): every row written so far is in the file
        with pytest.raises(ValueError, match="3 values for 2 columns"):
            log.write_values([1, 2, 3])
    tel = read_telemetry(path)
    assert tel.rows == 2000 and tel.dropped_lines == 0
    assert list(tel["t"]) == list(range(2000)) and tel["x"][1999] == 999.5


FULL_DISK = """
import resource, signal, sys
from hil.runtime.runlog import CsvLog
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
log = CsvLog(sys.argv[1], ["t", "a", "b"], batch_s=0.001)
try:
    for i in range(10_000):
        log.write_values([i * 0.01, 1.0 / 3.0, 2.0 / 3.0])
    log.close()
except OSError as exc:
    print("raised", exc.errno, flush=True)
    sys.exit(0)
print("not raised")
"""


def test_a_write_error_in_the_writer_thread_reaches_the_caller(tmp_path):
    """The disk refuses the rows (a file-size limit stands in for a full disk): the writer thread's error
    is raised on the caller's thread, never swallowed."""
    import errno

    done = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(tmp_path / "t.csv")], capture_output=True, text=True, timeout=60
    )
    assert done.stdout.strip() == f"raised {errno.EFBIG}", done.stdout + done.stderr
    tel = read_telemetry(tmp_path / "t.csv")  # what fitted is readable
    assert 50 < tel.rows < 200 and tel.dropped_lines <= 1


@pytest.mark.parametrize(
    ("make_root", "label", "why"),
    [
        (lambda tmp: tmp / "a-file" / "runs", "cubesat-1u", "Not a directory"),
        (lambda tmp: tmp / "nowhere", "x" * 300, None),  # a scenario's long name: cut, made
        (lambda tmp: tmp / ("y" * 300) / "runs", "cubesat-1u", "File name too long"),
    ],
)
def test_a_run_directory_that_cannot_be_made_is_a_config_error_naming_it(tmp_path, make_root, label, why):
    """Where a run's directory cannot be made (under a file, a name too long for the file system) the
    error names the path and why (it was an OSError's traceback, exit 1); a long label is cut."""
    from hil.runtime.runlog import new_run_dir
    from protocol.errors import ConfigError

    (tmp_path / "a-file").write_text("")
    root = make_root(tmp_path)
    if why is None:
        made = new_run_dir(root, label)
        assert made.is_dir() and len(made.name) < 100
        return
    with pytest.raises(ConfigError, match=why) as err:
        new_run_dir(root, label)
    assert str(root) in str(err.value)


def test_hil_run_into_a_directory_it_cannot_make_exits_2_with_the_path(tmp_path):
    (tmp_path / "a-file").write_text("")
    out = tmp_path / "a-file" / "runs"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--no-plots", "--duration", "1", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and str(out) in done.stderr and "cannot make" in done.stderr


def test_a_run_s_duration_past_a_day_is_refused_before_it_runs():
    from hil.runtime import RunOptions, run
    from hil.scenario import load_scenario
    from protocol.errors import ConfigError

    with pytest.raises(ConfigError, match="run --duration.*at most 86400 s"):
        run(load_scenario("cubesat-1u"), RunOptions(out_root=None, duration_s=1e9))
