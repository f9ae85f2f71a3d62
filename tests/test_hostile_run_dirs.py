"""A run directory's files damaged or hostile — one deeply nested events line, a nested or oversized
summary.json, a summary whose values are not what a run writes, a telemetry file that never ends its line,
binary bytes — into the readers' real entry points: ``hil report`` (as a process), ``hil gcs``'s source
and its server, :mod:`hil.runtime.runlog`. A damaged line is dropped and counted, a damaged summary is
reported as such; nothing dies, and memory stays bounded by what the files really hold."""

from __future__ import annotations

import json
import logging
import socket
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.gcs import GroundStation, RunDirSource
from hil.runtime.runlog import read_events, read_telemetry

MB = 1 << 20
NESTED = "[" * 100_000 + "]" * 100_000  # a JSON line nested 100 000 deep: a RecursionError in json.loads
SUMMARY = {"exit": "completed", "mode": "lockstep", "link": {"frames_in": 9, "rtt": {"p99_ms": 1.5}}}


def run_dir(d: Path, rows: int = 20, events: str = "", summary: str | None = None) -> Path:
    """A small run directory: telemetry rows, an events log of one good event (then ``events``), and a
    summary.json (``summary`` as given, or a good one)."""
    d.mkdir(parents=True, exist_ok=True)
    lines = "".join(f"{k / 50},1,{30 - k}\n" for k in range(rows))
    (d / "telemetry.csv").write_text("t,phase,point_err_deg\n" + lines)
    (d / "events.jsonl").write_text('{"t": 0.0, "kind": "armed"}\n' + events)
    (d / "summary.json").write_text(json.dumps(SUMMARY) if summary is None else summary)
    return d


def hil(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300)


# --------------------------------------------------------------------------- hil report
def test_hil_report_drops_and_counts_a_deeply_nested_events_line(tmp_path):
    d = run_dir(tmp_path / "run", events=f'{{"t": 1, "kind": {NESTED}}}\n{{"t": 2.0, "kind": "disarmed"}}\n')
    done = hil("report", str(d), "--no-plots")
    assert done.returncode == 0, done.stderr
    assert "20 telemetry rows, 2 events" in done.stdout
    assert "0 telemetry lines (damaged or out of time order), 1 event lines (dropped)" in done.stdout


def test_hil_report_says_a_nested_summary_is_damaged_and_goes_on(tmp_path):
    nested = json.dumps({"exit": "completed", "faults": json.loads("[" * 40 + "]" * 40)})
    d = run_dir(tmp_path / "run", summary=nested)
    done = hil("report", str(d))
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr
    assert "summary.json damaged (JSON nested deeper than 32 levels at faults" in done.stdout
    deeper = run_dir(tmp_path / "deeper", summary='{"exit": ' + NESTED + "}")
    done = hil("report", str(deeper), "--no-plots")
    assert done.returncode == 2 and "summary.json damaged (JSON nested deeper" in done.stdout, done.stderr


def test_hil_report_says_a_summary_of_the_wrong_shapes_is_damaged(tmp_path):
    """A fault without its time (the ``KeyError: 't'`` a hostile summary gave) and a tasks list."""
    shapes = {**SUMMARY, "faults": [{"kind": "stall"}], "tasks": ["control"]}
    d = run_dir(tmp_path / "run", summary=json.dumps(shapes))
    done = hil("report", str(d), "--no-plots")
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr
    assert "summary.json damaged (a value is not what a run writes: KeyError: 't')" in done.stdout


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [("settle_s", "Infinity", "settle_s is inf"), ("final_error_deg", "NaN", "final_error_deg is nan"),
     ("faults", '[{"t": 1.0, "kind": "stall", "at": -Infinity}]', "faults.0.at is -inf")],
)  # fmt: skip
def test_hil_report_says_a_summary_with_a_non_number_is_damaged(tmp_path, key, value, said):
    """NaN and Infinity parse as JSON in Python, and a run writes neither: an edited summary printed them
    as figures ("settle time inf s (met)"); it is damaged, naming the key, and not shown."""
    text = json.dumps({**SUMMARY, key: None}).replace(f'"{key}": null', f'"{key}": {value}')
    d = run_dir(tmp_path / "run", summary=text)
    done = hil("report", str(d), "--no-plots")
    assert done.returncode == 2 and "damaged" in done.stderr, done.stderr
    assert f"summary.json damaged (a value is not what a run writes: {said}): not shown" in done.stdout
    assert "settle time" not in done.stdout


def test_hil_report_of_a_telemetry_without_a_time_column_is_one_line_naming_it(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    (d / "telemetry.csv").write_text("x,y\n1,2\n")
    done = hil("report", str(d))
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"hil report: error: {d / 'telemetry.csv'}:1: no 't' column first (found 'x'): not a run's telemetry"
    ]


@pytest.mark.parametrize("damage", ["no time column", "a header too long to keep"])
def test_hil_gcs_of_a_telemetry_that_is_no_run_s_says_so_and_draws_nothing(tmp_path, damage):
    """Without its ``t`` column first, or with a header too long to keep, a run's telemetry is not
    streamed with another column (or its first data row) taken for the time: the page's status says
    why (it streamed 1930 rows with the phase for the time, status finished)."""
    d = run_dir(tmp_path / "run")
    lines = (d / "telemetry.csv").read_text().splitlines()
    if damage == "no time column":
        lines = [",".join(line.split(",")[1:]) for line in lines]
    else:
        lines[0] = lines[0] + ",x" * (MB // 2)
    (d / "telemetry.csv").write_text("\n".join(lines) + "\n")
    source = RunDirSource(d, follow=False)
    batch = source.poll()
    assert batch.info is None and not batch.rows
    assert (
        batch.status["state"] == "error"
        and "not" in batch.status["error"]
        and "telemetry" in batch.status["error"]
    )
    assert not source.poll().rows


@pytest.mark.parametrize("rows", [["x,y,z"] * 30, ["nan,1,2", "inf,1,2"], ["1e400,1,2"], ["1,2"]])
@pytest.mark.parametrize("summary", [None, "{"])
def test_hil_report_of_a_telemetry_whose_every_row_is_unreadable_says_the_file_is_damaged(
    tmp_path, rows, summary
):
    """A telemetry.csv with rows, none of them readable: it was said "no telemetry rows (the run ended
    before its first)", exit 0, as a run that never ran. The file is named damaged, exit 2 — with the
    summary's damage too when both are."""
    d = run_dir(tmp_path / "run", rows=0, summary=summary)
    (d / "telemetry.csv").write_text("t,phase,point_err_deg\n" + "\n".join(rows) + "\n")
    done = hil("report", str(d))
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert "the run ended before its first" not in done.stdout
    assert f"none of its {len(rows)} lines after the header is a readable row" in done.stdout
    said = done.stderr.strip().splitlines()[-1]
    if summary is None:
        assert f"{d / 'telemetry.csv'}: damaged (none of its {len(rows)} lines" in said, said
    else:
        assert f"{d / 'summary.json'}: damaged (" in said and "telemetry.csv damaged too (none of" in said


def test_hil_report_of_a_telemetry_of_no_rows_is_a_run_that_ended_before_its_first(tmp_path):
    d = run_dir(tmp_path / "run", rows=0)
    done = hil("report", str(d))
    assert done.returncode == 0, done.stderr
    assert "no telemetry rows (the run ended before its first): no plots" in done.stdout


# --------------------------------------------------------------------------- hil gcs RUN_DIR
def _stream_until_finished(station: GroundStation) -> list[dict]:
    """Every message of the station's event stream until the run directory is read to its end."""
    with socket.create_connection(("127.0.0.1", station.port), timeout=20) as s:
        s.sendall(f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
        data = b""
        while b'"state":"finished"' not in data:
            chunk = s.recv(65536)
            assert chunk, data[-300:]
            data += chunk
    body = data.partition(b"\r\n\r\n")[2].decode()
    messages = []
    for block in body.split("\n\n"):
        if block.startswith("event:"):
            kind = block.split("\n")[0].removeprefix("event: ")
            messages.append({"kind": kind, "data": json.loads(block.split("data: ", 1)[1])})
    return messages


def test_hil_gcs_streams_a_run_directory_with_a_nested_events_line_and_a_nested_summary(tmp_path):
    d = run_dir(
        tmp_path / "run",
        events=f"{NESTED}\n" + '{"t": 0.5, "kind": "spin_up"}\n',
        summary=json.dumps({"exit": "completed", "link": json.loads('{"a": ' * 40 + "1" + "}" * 40)}),
    )
    with GroundStation.replay(d, bind="127.0.0.1:0") as station:
        messages = _stream_until_finished(station)
    status = [m["data"] for m in messages if m["kind"] == "status"][-1]
    assert status["state"] == "finished" and status["bad_events"] == 1
    assert "unreadable summary: JSON nested deeper than 32 levels" in status["exit"]
    events = [e for m in messages if m["kind"] == "events" for e in m["data"]]
    assert [e["kind"] for e in events] == ["armed", "spin_up"]
    rows = [r for m in messages if m["kind"] == "rows" for r in m["data"]["rows"]]
    assert len(rows) == 20


def test_following_a_300_mb_telemetry_line_holds_at_most_a_line(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    with (d / "telemetry.csv").open("wb") as f:
        f.write(b"t,phase,point_err_deg\n0.0,1,30\n")
        block = b"0.02,1,29," * (MB // 10)  # never a line break
        for _ in range(300):
            f.write(block)
    source = RunDirSource(d, follow=False)
    tracemalloc.start()
    try:
        rows = 0
        for _ in range(200):
            batch = source.poll()
            rows += len(batch.rows)
            if batch.status and batch.status["state"] == "read":
                break
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert rows == 1 and source.bad_rows == 1 and batch.status["state"] == "read"
    assert peak < 24 * MB, f"{peak / MB:.0f} MB traced"


# --------------------------------------------------------------------------- the run log's readers
def test_read_telemetry_streams_and_drops_a_line_that_never_ends(tmp_path):
    path = tmp_path / "telemetry.csv"
    with path.open("wb") as f:
        f.write(b"t,x\n0.0,1.0\n")
        for _ in range(64):
            f.write(b"1," * (MB // 2))
        f.write(b"\n0.1,2.0\n\xff\xfe,3\n0.2,\n")
    tracemalloc.start()
    try:
        tel = read_telemetry(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert tel.rows == 3 and tel.dropped_lines == 2 and list(tel["x"][:2]) == [1.0, 2.0]
    assert peak < 16 * MB, f"{peak / MB:.0f} MB traced"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    lines=st.lists(
        st.one_of(
            st.binary(max_size=200),
            st.builds(lambda n: b"[" * n, st.integers(0, 5000)),
            st.builds(lambda n: b'{"t": 1, "a": ' * n + b"1" + b"}" * n, st.integers(0, 100)),
            st.sampled_from([b'{"t": 0.0, "kind": "armed"}', b"[]", b"null", b'"x"', b"", b"\x00" * 50]),
        ),
        max_size=20,
    ),
    long_line=st.booleans(),
)
def test_any_events_log_is_read_line_by_line_with_every_damaged_line_counted(tmp_path, lines, long_line):
    """Random lines: each is an event (a JSON object nested at most 32 deep) or one counted drop."""
    from hil.runtime.runlog import count_events

    path = tmp_path / "events.jsonl"
    body = b"\n".join(lines) + b"\n"
    if long_line:
        body += b"x" * (MB + 10) + b"\n"
    path.write_bytes(body)
    events, bad = read_events(path)
    assert all(isinstance(e, dict) for e in events)
    assert count_events(path) == (len(events), bad)
    assert len(events) + bad == len(body.replace(b"\r\n", b"\n").replace(b"\r", b"\n").split(b"\n")) - 1


# --------------------------------------------------------------------------- a campaign's directory
@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A real two-run campaign's directory (``hil montecarlo``, 3 s runs)."""
    from hil.cli import main

    out = tmp_path_factory.mktemp("mc") / "c"
    argv = ["montecarlo", "cubesat-1u", "--runs", "2", "--workers", "1", "--no-plots", "--duration", "3"]
    assert main([*argv, "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize(
    ("key", "value"),
    [("trace_samples", -5), ("trace_samples", 10**12), ("trace_samples", None), ("duration_s", "1e9"),
     ("trace_hz", 0), ("trace_hz", True)],
)  # fmt: skip
def test_hil_report_of_a_campaign_whose_manifest_was_edited_names_the_key(tmp_path, campaign, key, value):
    import shutil

    d = tmp_path / "c"
    shutil.copytree(campaign, d)
    info = json.loads((d / "campaign.json").read_text())
    if value is None:
        del info[key]
    else:
        info[key] = value
    (d / "campaign.json").write_text(json.dumps(info))
    done = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(d)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "campaign.json" in done.stderr and key in done.stderr


def test_a_campaign_s_traces_are_read_a_chunk_at_a_time_keeping_what_is_asked(tmp_path, campaign):
    """traces.bin grown to 64 MB (a hand-truncated file): read in chunks, only the traces asked for kept
    (it was read whole: a 1 GB file, 2.2 GB of memory)."""
    import shutil

    from hil.montecarlo import read_traces
    from hil.montecarlo.metrics import TRACES

    d = tmp_path / "c"
    shutil.copytree(campaign, d)
    index, traces = read_traces(d)
    with open(d / "traces.bin", "r+b") as f:
        f.truncate(64 * MB)  # zeros: records of zero bytes only
    tracemalloc.start()
    again, _ = read_traces(d, keep=[1])
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert list(index) == [0, 1] and traces.shape[:2] == (2, len(TRACES))
    assert list(again) == [1] and peak < 40 * MB


@pytest.mark.parametrize("tail", [1, 3, 1000])
def test_a_campaign_s_zero_filled_traces_tail_is_no_run_s_trace(tmp_path, campaign, caplog, tail):
    """Records of zero bytes after the real ones (what a crash leaves of appended blocks never written)
    read as run 0's trace, all zeros, the last record winning over run 0's own; they are left out,
    counted in a warning, and run 0's trace is its own."""
    import shutil

    from hil.montecarlo import read_traces
    from hil.montecarlo.store import read_manifest, trace_dtype

    d = tmp_path / "c"
    shutil.copytree(campaign, d)
    index, traces = read_traces(d)
    record = trace_dtype(int(read_manifest(d)["trace_samples"])).itemsize
    with open(d / "traces.bin", "ab") as f:
        f.write(bytes(record * tail))
    with caplog.at_level(logging.WARNING, logger="hil.montecarlo.store"):
        again, kept = read_traces(d)
    assert list(again) == list(index) == [0, 1]
    np.testing.assert_array_equal(kept, traces)
    assert np.any(kept[0] != 0.0)
    assert f"{tail} records of zero bytes only" in caplog.text


def test_a_campaign_s_duplicated_rows_are_counted_not_collapsed_silently(tmp_path, campaign):
    import shutil

    from hil.montecarlo import read_runs

    d = tmp_path / "c"
    shutil.copytree(campaign, d)
    lines = (d / "runs.csv").read_text().splitlines()
    (d / "runs.csv").write_text("\n".join([*lines, *lines[1:] * 50]) + "\n")
    results = read_runs(d)
    assert list(results.index) == [0, 1] and results.dropped == 100


# --------------------------------------------------------------------------- rows out of time order
ABSURD_TIMES = st.sampled_from([1e300, -1e300, 1e8, -1e8, float("nan"), float("inf"), -float("inf"), -5.0])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    absurd=st.lists(st.tuples(st.integers(1, 59), ABSURD_TIMES), max_size=4),  # -5 s first would be first
    replayed=st.lists(st.tuples(st.integers(1, 59), st.integers(0, 58), st.integers(1, 20)), max_size=1),
)
def test_rows_out_of_time_order_are_dropped_and_counted_by_every_reader(tmp_path_factory, absurd, replayed):
    """A row whose time is far off (1e300 s squashed every figure into its first pixel), not a number, or
    before a row already read (a file spliced or edited: rows repeated from earlier drew the run twice over
    itself) is dropped and counted — by ``read_telemetry`` (hil report, the plots) and by ``hil gcs``'s
    run-directory source alike — and every row of the run in order is kept."""
    times = [k / 50 for k in range(60)]
    rows = [(t, True) for t in times]
    for at, start, length in replayed:  # a stretch that ended before row ``at`` written again after it
        if start + length < at:
            rows[at:at] = [(t, False) for t, _ in rows[start : start + length]]
    for at, t in absurd:
        rows.insert(at, (t, False))
    d = tmp_path_factory.mktemp("ordered")
    (d / "telemetry.csv").write_text(
        "t,phase,point_err_deg\n" + "".join(f"{'' if t != t else repr(t)},1,2\n" for t, _ in rows)
    )
    kept = [t for t, good in rows if good]
    tel = read_telemetry(d / "telemetry.csv")
    assert tel["t"].tolist() == kept and tel.dropped_lines == len(rows) - len(kept)
    source = RunDirSource(d, follow=False)
    batch = source.poll()
    assert [row[0] for row in batch.rows] == kept and source.bad_rows == len(rows) - len(kept)
