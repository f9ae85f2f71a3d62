"""Campaigns beside the path: dispersion files whose values parse but are absurd, a campaign directory
damaged between sessions (a manifest that is no object, a runs.csv of another header or none of its
manifest, rows whose index or metric is no number, a FIFO where a file should be, a disk that fills up),
scheduler addresses that name nothing or answer with something else, and an interrupt while the local
cluster starts. Each is a typed error naming where, or a counted drop — never a traceback, a hang, or a
run silently lost or written twice.

Most tests need no simulation (a campaign directory is written with :class:`ResultStore` from results
made here); one resumes a real campaign on an in-process cluster (two 1.5 s runs).
"""

from __future__ import annotations

import csv
import json
import math
import os
import resource
import signal
import socket
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil.cli._signals import interrupts_raise, signal_of
from hil.montecarlo import Campaign, draw, open_client, parse_dispersions, read_runs, run_campaign
from hil.montecarlo.campaign import check_address
from hil.montecarlo.dispersions import OUTAGE_S
from hil.montecarlo.fault_plan import MAX_COUNT, MIN_DURATION_S, run_window_s
from hil.montecarlo.metrics import METRICS, TRACES, trace_length
from hil.montecarlo.runner import RunResult
from hil.montecarlo.store import MANIFEST, RUNS, TRACE_FILE, ResultStore
from hil.runtime.held_signals import deferred
from hil.scenario import load_scenario
from protocol.errors import ConfigError, LinkError

SETTINGS = settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """cubesat-1u, shortened: 0.5 s warm-up, a 20° slew, 1 s after its start."""
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


# --------------------------------------------------------------------------- absurd dispersion files
@pytest.mark.parametrize(
    ("text", "where"),
    [
        ('[spacecraft]\ninertia_scale = { dist = "normal", sigma = 1e160 }\n',
         "spacecraft.inertia_scale.sigma"),
        ('[manoeuvre]\nangle_deg = { dist = "normal", relative_sigma = 1e308 }\n',
         "manoeuvre.angle_deg.relative_sigma"),
        ('[link]\noutages_per_minute = 1.0\n'
         'outage_duration_s = { dist = "normal", mean = 0.5, sigma = 1e160 }\n',
         "link.outage_duration_s.sigma"),
        ("[link]\noutages_per_minute = 1.0\noutage_duration_s = 0\n", "link.outage_duration_s"),
        ("[faults]\nstall = { count = 1, duration_s = 0 }\n", "faults.stall.duration_s"),
        ("[faults]\nphone_gap = { count = 1, duration_s = 0.0 }\n", "faults.phone_gap.duration_s"),
        ("[faults]\nphone_jump = { count = 1, offset_s = 1e6 }\n", "faults.phone_jump.offset_s"),
        ('[faults]\nhang = { count = { dist = "normal", mean = 1, sigma = 1e160 } }\n',
         "faults.hang.count.sigma"),
    ],
)  # fmt: skip
def test_a_spread_or_a_value_no_run_can_take_is_refused_naming_file_and_key(scenario, text, where):
    """σ = 1e160 pinned every draw to the ends of the parameter's range (every run ±100 × the inertia);
    relative σ 1e308 overflowed to inf (a RuntimeWarning); an outage or fault of no time, or a phone clock
    jump beyond the world's ±86 400 s, made every run fail (a fault campaign counted each as the run's own
    crash): now the file is refused, naming itself and the key."""
    with pytest.raises(ConfigError) as info:
        parse_dispersions(text, scenario, "absurd.toml")
    assert info.value.where == f"absurd.toml: {where}"


@SETTINGS
@given(
    mean=st.floats(0.0, 60.0),
    sigma=st.floats(0.0, 60.0),
    seed=st.integers(0, 2**63 - 1),
    index=st.integers(0, 10**7),
)
def test_every_drawn_outage_is_one_the_board_takes(scenario, mean, sigma, seed, index):
    """A normal outage duration's tail drew negative durations (the board refused ``--stall T:-0.15``: the
    run failed) and, with a wide σ, durations of 1e160 s: each is clipped into 1 ms..60 s."""
    text = (
        "[link]\noutages_per_minute = 600.0\n"
        f'outage_duration_s = {{ dist = "normal", mean = {mean!r}, sigma = {sigma!r} }}\n'
    )
    run = draw(parse_dispersions(text, scenario), seed, index)
    assert all(OUTAGE_S[0] <= d <= OUTAGE_S[1] for _, d in run.outages)
    assert math.isfinite(float(run.columns["link.outage_s"]))


@SETTINGS
@given(low=st.floats(0.0, 1.0), seed=st.integers(0, 2**32), per_minute=st.floats(0.0, 600.0))
def test_drawn_faults_stay_within_what_the_board_and_world_take(scenario, low, seed, per_minute):
    """A fault's drawn duration clipped to 0 (``--stall T:0.0`` refused, the run counted as crashed) is at
    least 1 ms; a rate's Poisson count is at most MAX_COUNT like a count's (600 a minute over a 10-minute
    run drew ~6 000 stalls a run) — and a rate whose count could pass it is refused as the file is read,
    naming the key (it was clipped silently: 600 a minute gave exactly 100 faults in every run)."""
    long = scenario.with_changes(slew=replace(scenario.slew, duration_s=600.0))
    text = (
        f'[faults]\nstall = {{ per_minute = {per_minute!r}, duration_s = {{ dist = "normal", mean = {low!r}, '
        "sigma = 1.0 } }\n"
    )
    expected = per_minute * run_window_s(long) / 60.0
    if expected + 5.0 * math.sqrt(expected) > MAX_COUNT:
        with pytest.raises(ConfigError, match="faults.stall.per_minute") as refused:
            parse_dispersions(text, long)
        assert f"a run takes at most {MAX_COUNT}" in str(refused.value)
        return
    faults = draw(parse_dispersions(text, long), seed, 0).faults
    assert faults is not None and len(faults) <= MAX_COUNT
    assert all(MIN_DURATION_S <= f.params["duration_s"] <= 60.0 for f in faults)


# --------------------------------------------------------------------------- a damaged campaign directory
def _result(index: int, ok: bool = True, samples: int = 5) -> RunResult:
    columns = {f"spacecraft.inertia_scale.{a}": 1.0 + index / 100 for a in "xyz"}
    metrics = {name: float(index) for name in METRICS}
    trace = np.full((len(TRACES), samples), index, dtype=np.float32)
    return RunResult(index, ok, columns, metrics if ok else {}, trace if ok else None, "" if ok else "E: x")


@pytest.mark.parametrize("trace_hz", [1e-300, 1e-9, 0.01])
def test_a_trace_rate_that_samples_no_run_once_is_refused_naming_it(scenario, trace_hz):
    """A trace rate below one sample in the slew's duration made every run's trace empty, and ``hil report``
    then took run 0's record (its index alone, 0) for a crash's unwritten tail."""
    if trace_length(scenario.slew.duration_s, trace_hz) >= 1:  # 0.01 Hz: one sample, at the slew's start
        Campaign(
            scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=1, seed=0, trace_hz=trace_hz
        )
        return
    with pytest.raises(ConfigError, match="samples no run's trace") as err:
        Campaign(
            scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=1, seed=0, trace_hz=trace_hz
        )
    assert err.value.where == "campaign.trace_hz"


@pytest.fixture
def campaign(scenario):
    return Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=4, seed=1)


@pytest.fixture
def made(tmp_path, campaign):
    """A campaign directory holding runs 0 and 1 (written as a session writes them)."""
    out = tmp_path / "mc"
    with ResultStore(out, campaign.manifest()) as store:
        for i in range(2):
            store.append(_result(i))
    return out


def _set_header(out: Path, change) -> None:
    lines = (out / RUNS).read_text().splitlines()
    lines[0] = change(lines[0])
    (out / RUNS).write_text("\n".join(lines) + "\n")


def _fifo(path: Path) -> None:
    path.unlink(missing_ok=True)
    os.mkfifo(path)


@pytest.mark.parametrize(
    ("damage", "file", "said"),
    [
        (lambda d: (d / MANIFEST).write_text("[]"), MANIFEST, "not a JSON object"),
        (lambda d: (d / MANIFEST).write_text("[" * 100_000 + "]" * 100_000), MANIFEST, "nested deeper"),
        (lambda d: (d / MANIFEST).unlink(), RUNS, "without a campaign.json"),
        (lambda d: _set_header(d, lambda h: h.replace("final_error_deg", "fe")), RUNS, "column 8 is 'fe'"),
        (lambda d: _set_header(d, lambda h: h + ",extra"), RUNS, "a column too many"),
        (lambda d: (d / RUNS).write_bytes(b"\xff\xfe\x00garbage\n"), RUNS, "header is not"),
        (lambda d: ((d / RUNS).unlink(), (d / RUNS).mkdir()), RUNS, "not a regular file"),
        (lambda d: _fifo(d / RUNS), RUNS, "not a regular file"),
        (lambda d: _fifo(d / TRACE_FILE), TRACE_FILE, "not a regular file"),
    ],
)
def test_a_directory_this_campaign_cannot_resume_is_refused_naming_the_file(
    made, campaign, damage, file, said
):
    """Before: a manifest that is a JSON list (AttributeError) or nested 100 000 deep (RecursionError); a
    runs.csv without its manifest adopted as this campaign's; rows appended under another header, read
    back as malformed (every new row dropped) or under the wrong names; a binary header a
    UnicodeDecodeError; a directory an IsADirectoryError; a FIFO waited on for ever."""
    damage(made)
    before = {p.name: p.stat().st_size for p in made.iterdir() if p.is_file()}
    with pytest.raises(ConfigError, match=said) as info:
        ResultStore(made, campaign.manifest())
    assert info.value.where == str(made / file)
    assert {p.name: p.stat().st_size for p in made.iterdir() if p.is_file()} == before  # nothing written


@pytest.mark.parametrize(
    "line",
    ["²,ok,,1,1,1" + ",1" * len(METRICS), "9" * 5000 + ",ok,,1,1,1" + ",1" * len(METRICS),
     f"{2**31},ok,,1,1,1" + ",1" * len(METRICS), "2,ok,,1,1,1,abc" + ",1" * (len(METRICS) - 1),
     '3,ok,"unterminated' + ",1" * 20],
)  # fmt: skip
def test_a_row_whose_index_or_metric_is_no_number_is_dropped_and_counted(made, campaign, line):
    """Before: an index of '²' (str.isdigit) or of 5 000 digits was a ValueError out of every reader; an
    index past int32 was kept (traces.bin's index is an int32); one metric cell of text turned the whole
    column into text — that metric gone from the summary, its requirement failed by every run."""
    with open(made / RUNS, "a") as f:
        f.write(line + "\n")
    results = read_runs(made)
    assert results.index.tolist() == [0, 1] and results.dropped == 1
    assert set(METRICS) <= set(results.values)
    with ResultStore(made, campaign.manifest()) as store:  # and a session resumes it
        assert store.finished == {0, 1}


@SETTINGS
@given(junk=st.lists(st.text(max_size=40), max_size=6))
def test_any_junk_lines_in_runs_csv_are_counted_never_raised(tmp_path_factory, campaign, junk):
    out = tmp_path_factory.mktemp("junk")
    with ResultStore(out, campaign.manifest()) as store:
        store.append(_result(0))
    with open(out / RUNS, "a", newline="") as f:
        for line in junk:
            f.write(line.replace("\n", " ").replace("\r", " ") + "\n")
    results = read_runs(out)
    assert 0 in results.index.tolist() and len(results) + results.dropped >= 1


@pytest.mark.parametrize("left", [b"", b"index,status,err"])
def test_a_session_stopped_before_its_header_reached_the_disk_resumes(made, campaign, left):
    """Ctrl-C (or SIGKILL) between runs.csv's creation and its header's flush leaves it empty or torn
    in its header: that directory could not be resumed ('not a campaign's runs.csv (header None)')."""
    (made / RUNS).write_bytes(left)
    (made / TRACE_FILE).write_bytes(b"")
    with ResultStore(made, campaign.manifest()) as store:
        assert store.finished == set()
        store.append(_result(2))
    assert read_runs(made).index.tolist() == [2]


def test_a_full_disk_is_an_error_naming_the_file_and_loses_no_written_run(made, campaign):
    """A write the OS refuses (here the file-size limit, EFBIG, as a full disk's ENOSPC) was an OSError's
    traceback; it is a ConfigError naming the file, and the rows written before it read back whole."""
    limit = (made / RUNS).stat().st_size + 300
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        with pytest.raises(ConfigError, match="cannot write") as info:  # noqa: PT012
            with ResultStore(made, campaign.manifest()) as store:
                for i in range(2, 200):
                    store.append(_result(i, ok=False))
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert info.value.where == str(made / RUNS)
    results = read_runs(made)
    assert results.index.tolist()[:2] == [0, 1] and results.dropped <= 1  # at most the torn last line
    with ResultStore(made, campaign.manifest()) as store:  # the next session cuts it off and goes on
        assert {0, 1} <= store.finished and max(store.finished) < 200


def test_a_resumed_campaign_of_a_damaged_directory_runs_every_run_once(scenario, campaign, made):
    """A real session on a directory left with a torn row, a row of text metrics and an orphan trace:
    every run ends in runs.csv exactly once, and the summary counts the dropped lines."""
    with open(made / RUNS, "a") as f:
        f.write("3,ok,,1,1,1,abc" + ",1" * (len(METRICS) - 1) + "\n")  # run 3: damaged, run again
        f.write("2,ok,,1.0,2")  # torn
    with open(made / TRACE_FILE, "ab") as f:
        f.write(b"\x07\x00")
    with open_client(workers=1, processes=False) as client:
        report = run_campaign(campaign, made, client, plots=False)
    assert report.skipped == 2 and report.completed == 2
    with open(made / RUNS, newline="") as f:
        indices = [row[0] for row in list(csv.reader(f))[1:]]
    assert sorted(indices) == ["0", "1", "2", "3", "3"]  # the damaged row of 3 stays, counted
    results = read_runs(made)
    assert results.index.tolist() == [0, 1, 2, 3] and results.dropped == 1
    summary = json.loads((made / "summary.json").read_text())
    assert summary["runs"] == 4 and summary["dropped_lines"] == 1


def test_a_campaign_of_ten_million_runs_holds_only_its_window(scenario, campaign, tmp_path):
    """--runs 10⁷: nothing is held per run before it runs — interrupted after two results, the driver
    has drawn only a window of chunks."""
    import tracemalloc

    big = replace(campaign, runs=10**7, batch=1)
    drawn = []

    def stop(result, done, total):
        if done >= 2:
            raise KeyboardInterrupt

    original = Campaign.draw
    tracemalloc.start()
    try:
        with open_client(workers=1, processes=False) as client:
            Campaign.draw = lambda self, i: drawn.append(i) or original(self, i)  # type: ignore[method-assign]
            with pytest.raises(KeyboardInterrupt):
                run_campaign(big, tmp_path / "big", client, on_result=stop, plots=False)
    finally:
        Campaign.draw = original  # type: ignore[method-assign]
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert len(drawn) <= 8 and peak < 64 << 20
    assert read_runs(tmp_path / "big").index.tolist() == [0, 1]


# --------------------------------------------------------------------------- schedulers that are not
@pytest.mark.parametrize(
    ("address", "said"),
    [("nonsense", "not a scheduler address"), ("tcp://[::1", "not a scheduler address"),
     ("tcp://127.0.0.1", "not a scheduler address"), ("tcp://127.0.0.1:99999", "port 99999"),
     ("tls://127.0.0.1:8786", "TLS configuration")],
)  # fmt: skip
def test_a_scheduler_address_that_names_no_scheduler_is_refused(address, said):
    """Before: Dask's ValueError or TypeError ('TLS expects a ssl_context ...') with its traceback, or a
    10 s wait for a port beyond 65535."""
    with pytest.raises(ConfigError, match=said) as info:
        check_address(address)
    assert info.value.where == "scheduler"
    with pytest.raises(ConfigError), open_client(address):
        pass


def test_an_in_process_address_that_names_no_scheduler_is_a_link_error():
    """inproc:// (a scheduler in this process, as tests use) is not probed; one that is not there was
    Dask's ValueError ('not enough values to unpack') with its traceback."""
    with pytest.raises(LinkError, match="inproc://x"), open_client("inproc://x"):
        pass


@pytest.mark.parametrize("answer", [b"HTTP/1.1 400 Bad Request\r\n\r\n" * 4, b""])
def test_a_scheduler_address_where_something_else_answers_is_a_bounded_link_error(answer):
    """Something that answers, not as a scheduler (an HTTP server: Dask read its bytes as a frame length
    and numpy was asked for 3 EiB, a MemoryError's traceback), or a port that accepts and never speaks:
    a LinkError naming the address, within the timeout."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    held: list[socket.socket] = []

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            held.append(conn)
            if answer:
                conn.sendall(answer)

    threading.Thread(target=serve, daemon=True).start()
    start = time.monotonic()
    try:
        with (
            pytest.raises(LinkError, match=f"127.0.0.1:{port}"),
            open_client(f"tcp://127.0.0.1:{port}", timeout_s=2.0),
        ):
            pass
    finally:
        server.close()
        for conn in held:
            conn.close()
    assert time.monotonic() - start < 15.0


# --------------------------------------------------------------------------- interrupts while starting
def test_an_interrupt_while_the_cluster_starts_is_handled_once_it_is_up():
    """SIGINT while a LocalCluster started left it half-made (Dask's exit hook then failed an assertion,
    with a traceback, or the start failed with 'Nanny failed to start'): the interrupt is held for the
    block and raised after it — or instead of the block's own error when the block failed."""
    with pytest.raises(KeyboardInterrupt):
        with deferred():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            reached = True  # the block went on
    assert reached
    with pytest.raises(KeyboardInterrupt):
        with deferred():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)
            raise RuntimeError("Nanny failed to start.")
    with pytest.raises(RuntimeError), deferred():  # no interrupt: the block's own error
        raise RuntimeError("Nanny failed to start.")
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_every_signal_that_stops_a_command_is_held_while_the_cluster_starts(signum):
    """Under hil's handlers (``hil.cli._signals``: SIGINT, SIGTERM and SIGHUP all stop a command): a closed
    terminal's SIGHUP went through the cluster's start (only SIGINT and SIGTERM were held), leaving it half
    made. Each is held, then raised as the command's interrupt, naming it."""
    with interrupts_raise():
        with pytest.raises(KeyboardInterrupt) as info:
            with deferred():
                os.kill(os.getpid(), signum)
                time.sleep(0.05)
                reached = True
        assert reached
        assert signal_of(info.value) == signum
