"""How ``hil run`` ends when it is signalled, its terminal closes or its disk fills, and what its run
directory then says — real processes, real signals, a real pty, a real file-size limit.

Beside the path tests/test_sigterm.py walks (one SIGINT or SIGTERM mid-run), these once broke:

* SIGHUP (the terminal or ssh session closed) ended the run at once: status 129, no summary.json, no
  Disarm; and a progress line written to a terminal that had hung up (EIO) or a pipe whose reader was gone
  (EPIPE) ended the run as an error, the board left armed;
* a second Ctrl-C within milliseconds of the first (while the run wrote its ending) left no summary.json,
  or one without its ``exit``;
* Ctrl-C while the plots were drawn exited 130 with the plotter still drawing after ``hil`` had gone;
* a disk that filled mid-run (a file-size limit stands in: EFBIG, as ENOSPC) ended in an OSError's
  traceback, telemetry.csv torn at its last line and the board not disarmed.

Every wait is a deadline loop on what the process wrote; the runs are paced lockstep runs of the built-in
emulator, so the moments are drawn in the run's own (simulated) time.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import pty
import resource
import select
import signal
import subprocess
import sys
import termios
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from observer_support import SilentObserver
from test_sigterm import _text, _wait_until

from hil.runtime.runlog import read_events, read_telemetry
from hil.scenario.paths import ROOT

NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM", signal.SIGHUP: "SIGHUP"}
SLEW_START_S, SLEW_END_S = 3.7, 23.3  # cubesat-1u in lockstep: spin-up at 2.1 s, the slew, then the hold
PACED = ("--pace", "8", "--duration", "30")  # ends at ~34 s simulated: ~4 s of wall time, or more if loaded
DRAWN = settings(
    max_examples=4,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def _spawn(tmp: Path, *args: str, **kw) -> subprocess.Popen:
    """``hil run ARGS --out tmp/runs`` with stdout and stderr into tmp/hil.out and tmp/hil.err (unless
    ``kw`` gives its own)."""
    files = []
    if "stdout" not in kw:
        files.append(open(tmp / "hil.out", "w"))  # noqa: SIM115 — the child holds it; closed below
        kw["stdout"] = files[-1]
    if "stderr" not in kw:
        files.append(open(tmp / "hil.err", "w"))  # noqa: SIM115
        kw["stderr"] = files[-1]
    try:
        cmd = [sys.executable, "-m", "hil", "run", *args, "--out", str(tmp / "runs")]
        return subprocess.Popen(cmd, cwd=ROOT, **kw)
    finally:
        for f in files:
            f.close()


def _run_dir(tmp: Path) -> Path | None:
    dirs = sorted((tmp / "runs").glob("*/telemetry.csv")) if (tmp / "runs").exists() else []
    return dirs[0].parent if dirs else None


def _last_t(tmp: Path) -> float:
    """The time of telemetry.csv's last whole row (-1 before there is one)."""
    run_dir = _run_dir(tmp)
    if run_dir is None:
        return -1.0
    with open(run_dir / "telemetry.csv", "rb") as f:
        f.seek(0, os.SEEK_END)
        f.seek(max(0, f.tell() - 8192))
        lines = f.read().split(b"\r\n")[:-1]  # the last element: a row still being written, or b""
    try:
        return float(lines[-1].split(b",", 1)[0]) if lines else -1.0
    except ValueError:  # the header
        return -1.0


def _ended(proc: subprocess.Popen, timeout: float = 60.0) -> int:
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise AssertionError(f"hung: still running {timeout} s after it was signalled") from None


def _honest_run_dir(run_dir: Path, logs: bool = True) -> dict:
    """What every run directory must be however its run ended: summary.json whole JSON with an exit,
    telemetry.csv and events.jsonl (there unless not ``logs``: a disk full before they were made) ending at
    a whole line with no damaged one, no temporary file left. Returns the summary."""
    summary = json.loads((run_dir / "summary.json").read_text())
    assert isinstance(summary.get("exit"), str), summary
    assert not list(run_dir.glob("*.tmp"))
    if not logs and not (run_dir / "events.jsonl").exists():
        assert not (run_dir / "telemetry.csv").exists()
        return summary
    csv = (run_dir / "telemetry.csv").read_bytes() if (run_dir / "telemetry.csv").exists() else b""
    if logs or csv:  # a disk full at its first write leaves it empty: nothing torn
        assert csv.endswith(b"\r\n"), csv[-200:]
        assert read_telemetry(run_dir / "telemetry.csv").dropped_lines == 0
    events_text = (run_dir / "events.jsonl").read_bytes()
    assert events_text == b"" or events_text.endswith(b"\n")
    events, bad = read_events(run_dir / "events.jsonl")
    assert bad == 0
    assert [e["t"] for e in events] == sorted(e["t"] for e in events)
    return summary


def interrupted_by(first: int, second: tuple[int, float] | None) -> set[str]:
    """The exits a run signalled ``first``, then maybe ``second`` (signal, gap s), may name. Two signals
    sent within milliseconds may both be pending when the process next runs Python, which handles pending
    signals by number (SIGINT before SIGTERM), not in the order they were sent: either is named then."""
    names = {NAMES[first]} if second is None else {NAMES[first], NAMES[second[0]]}
    return {f"interrupted ({name})" for name in names}


def _disarms(run_dir: Path) -> list[tuple[str, str]]:
    events = read_events(run_dir / "events.jsonl")[0]
    return [(e["kind"], e["reason"]) for e in events if e["kind"] in ("disarmed", "disarm_failed")]


@given(
    first=st.sampled_from(sorted(NAMES)),
    moment=st.one_of(
        st.tuples(st.just("wall"), st.floats(0.0, 2.5)),  # imports, kernels, the first handshake
        st.tuples(st.just("sim"), st.floats(0.0, 26.0)),  # warm-up, spin-up, slew, hold
    ),
    second=st.none() | st.tuples(st.sampled_from(sorted(NAMES)), st.floats(0.0, 0.005)),
)
@DRAWN
def test_a_signal_at_a_drawn_moment_ends_the_run_honestly(tmp_path_factory, first, moment, second):
    """SIGINT, SIGTERM or SIGHUP at a drawn moment of the run, maybe a second one (any of them) right after:
    the process ends, with no run directory at all (signalled before the run started: 128 + the signal,
    or the signal's own death while Python was still starting) or with an honest one — summary.json
    saying ``interrupted (SIG...)`` for the first signal, whole lines, the armed board disarmed once."""
    tmp = tmp_path_factory.mktemp("drawn")
    hil = _spawn(tmp, *PACED, "--no-plots")
    try:
        kind, at = moment
        if kind == "wall":
            time.sleep(at)
        else:
            _wait_until(lambda: _last_t(tmp) >= at, 120.0, f"the run at {at:.2f} s", hil)
        hil.send_signal(first)
        if second is not None:
            time.sleep(second[1])
            if hil.poll() is None:
                hil.send_signal(second[0])
        status = _ended(hil)
    finally:
        if hil.poll() is None:
            hil.kill()
            hil.wait()
    err = _text(tmp / "hil.err")
    run_dir = _run_dir(tmp)
    if run_dir is None or not (run_dir / "summary.json").exists():
        assert run_dir is None, f"a run directory without summary.json; status {status}; {err[-2000:]}"
        sent = [first] if second is None else [first, second[0]]  # either may be handled first (above)
        allowed = {128 + s for s in sent} | {-s for s in sent} | ({1} if signal.SIGINT in sent else set())
        assert status in allowed, (status, err)
        return
    assert status == 1, f"status {status}: {err[-2000:]}"
    assert "Traceback" not in err, err
    summary = _honest_run_dir(run_dir)
    assert summary["exit"] in interrupted_by(first, second)
    disarms = _disarms(run_dir)
    events = [e["kind"] for e in read_events(run_dir / "events.jsonl")[0]]
    if "armed" in events:
        assert len(disarms) == 1 and disarms[0][1] == summary["exit"], disarms
        assert disarms[0][0] == "disarmed", disarms  # a second signal is held: the Disarm's wait goes on


@pytest.mark.parametrize("gap_s", [0.0005, 0.003])
def test_a_second_interrupt_at_once_leaves_the_summary_whole(tmp_path, gap_s):
    """Ctrl-C twice in a row, as a user does: the second one (``gap_s`` after the first: two at the same
    instant are one pending signal) used to land in the run's clean-up and leave no summary.json (or one
    without ``exit``), status 130."""
    hil = _spawn(tmp_path, *PACED, "--no-plots")
    try:
        _wait_until(lambda: _last_t(tmp_path) >= 5.0, 120.0, "the slew under way", hil)
        hil.send_signal(signal.SIGINT)
        time.sleep(gap_s)
        hil.send_signal(signal.SIGINT)
        status = _ended(hil)
    finally:
        if hil.poll() is None:
            hil.kill()
            hil.wait()
    assert status == 1, _text(tmp_path / "hil.err")[-2000:]
    run_dir = _run_dir(tmp_path)
    assert run_dir is not None
    summary = _honest_run_dir(run_dir)
    assert summary["exit"] == "interrupted (SIGINT)"
    assert [k for k, _ in _disarms(run_dir)] == ["disarmed"]
    assert "exit              interrupted (SIGINT)" in _text(tmp_path / "hil.out")


def test_a_signal_as_the_run_directory_appears_still_leaves_a_summary(tmp_path):
    """SIGTERM the moment the run directory exists: it used to be made before git's revision was asked for
    and its files written, ~20 ms in which an interrupt left an empty directory (status 143); it is now
    made where the run's ending covers it — a summary.json saying ``interrupted (SIGTERM)``, status 1."""
    hil = _spawn(tmp_path, *PACED, "--no-plots")
    runs = tmp_path / "runs"
    try:
        deadline = time.monotonic() + 120.0
        while not (runs.exists() and any(runs.iterdir())):
            assert time.monotonic() < deadline and hil.poll() is None, _text(tmp_path / "hil.err")
            time.sleep(0.0005)
        hil.send_signal(signal.SIGTERM)
        status = _ended(hil)
    finally:
        if hil.poll() is None:
            hil.kill()
            hil.wait()
    run_dir = next(runs.iterdir())
    assert status == 1, f"status {status}: {_text(tmp_path / 'hil.err')[-2000:]}"
    assert _honest_run_dir(run_dir, logs=False)["exit"] == "interrupted (SIGTERM)"


def _controlling_tty() -> None:
    """In the child (after its setsid): the pty on its stdin becomes its controlling terminal, so closing
    the pty's master hangs it up (SIGHUP, and EIO on every later write) as a closed ssh session does."""
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def test_a_closed_terminal_ends_the_run_like_sigterm(tmp_path):
    """`hil run` in a terminal that goes away (an ssh session dropped): the kernel sends SIGHUP and every
    later write to the terminal fails with EIO. The run used to die at once (status 129, no summary, no
    Disarm); now it ends as SIGTERM ends it: summary.json ``interrupted (SIGHUP)``, the board disarmed,
    status 1 — the summary it could not print is in the run directory."""
    master, slave = pty.openpty()
    draining = threading.Event()
    draining.set()

    def drain() -> None:  # the terminal's reader: a full pty would stall the run's progress line
        while draining.is_set():
            if select.select([master], [], [], 0.05)[0]:
                try:
                    os.read(master, 65536)
                except OSError:
                    return

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        hil = _spawn(
            tmp_path,
            *PACED,
            "--no-plots",
            stdin=slave,
            stdout=slave,
            stderr=slave,
            start_new_session=True,
            preexec_fn=_controlling_tty,
        )
    finally:
        os.close(slave)
    try:
        _wait_until(lambda: _last_t(tmp_path) >= 2.5, 120.0, "the rotors spun up", hil)
        draining.clear()
        reader.join()
        os.close(master)  # the terminal hangs up
        status = _ended(hil)
    finally:
        if hil.poll() is None:
            hil.kill()
            hil.wait()
    assert status == 1
    run_dir = _run_dir(tmp_path)
    assert run_dir is not None
    summary = _honest_run_dir(run_dir)
    assert summary["exit"] == "interrupted (SIGHUP)"
    assert _disarms(run_dir) == [("disarmed", "interrupted (SIGHUP)")]


def test_a_progress_line_nobody_reads_does_not_end_the_run(tmp_path):
    """`hil run 2>&1 | tee log` whose tee is gone (its terminal closed, nohup kept hil): the progress
    line's write fails with EPIPE. That ended the run as ``error: [Errno 32] Broken pipe`` with a
    traceback and the board left armed; the run now carries on and completes."""
    read_end, write_end = os.pipe()
    try:
        hil = _spawn(tmp_path, "--duration", "3", "--no-plots", stderr=write_end)
    finally:
        os.close(write_end)
    os.close(read_end)  # nobody reads hil's stderr from the start
    status = _ended(hil, timeout=300)
    run_dir = _run_dir(tmp_path)
    assert run_dir is not None
    summary = _honest_run_dir(run_dir)
    assert summary["exit"] == "completed"
    assert status == 0
    assert "exit              completed" in _text(tmp_path / "hil.out")


def _session_of(pid: int) -> list[int]:
    """The processes whose process group is ``pid`` (the plotter's own session: it and its forks)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pid and fields[0] != "Z":
                found.append(int(entry.name))
    return found


def _plotters(pid: int) -> list[int]:
    """``pid``'s children that are hil run's plotter (``python -m hil.cli._plotter``)."""
    text = _text(Path(f"/proc/{pid}/task/{pid}/children"))
    return [int(p) for p in text.split() if b"hil.cli._plotter" in _cmdline(int(p))]


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


@given(delay=st.floats(0.0, 0.15))
@DRAWN
def test_an_interrupt_while_the_plots_are_drawn_stops_them(tmp_path_factory, delay):
    """Ctrl-C after the run, while its summary prints and its plots are drawn (by a process of its own
    session, which forks to draw): status 1 with what is left undone said, no drawing process left behind
    (it once exited 130 and left the plotter drawing), summary.json as the run ended."""
    tmp = tmp_path_factory.mktemp("plots")
    hil = _spawn(tmp, "--duration", "2")
    try:
        _wait_until(lambda: _plotters(hil.pid), 60.0, "the plotter started", hil)
        plotter = _plotters(hil.pid)[0]
        _wait_until(lambda: "run directory:" in _text(tmp / "hil.out"), 300.0, "the run's end", hil)
        time.sleep(delay)
        hil.send_signal(signal.SIGINT)
        status = _ended(hil)
    finally:
        if hil.poll() is None:
            hil.kill()
            hil.wait()
    left = _session_of(plotter)
    for pid in left:  # not to leave them to the next test either
        os.kill(pid, signal.SIGKILL)
    assert left == [], "the plotter's processes outlived hil"
    err = _text(tmp / "hil.err")
    run_dir = _run_dir(tmp)
    assert run_dir is not None
    assert _honest_run_dir(run_dir)["exit"] == "completed"
    if "interrupted" in err:  # the signal came before the figures were all drawn
        assert status == 1, err
        assert (
            f"interrupted (SIGINT) after the run ended: plots not drawn or not all (hil report {run_dir}"
            in err
        )
    else:  # they were drawn already: the run completed, nothing was left undone
        assert status == 0, err
    assert "Traceback" not in err


def _file_size_limit(limit: int) -> Callable[[], None]:
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))  # Python ignores SIGXFSZ: EFBIG instead

    return apply


@pytest.mark.parametrize("limit", [64, 1500, 6000, 40_000, 150_000])
def test_a_disk_that_fills_mid_run_ends_it_with_an_error_not_a_traceback(tmp_path_factory, limit):
    """A file-size limit stands in for a full disk, swept over the run's writes: scenario.toml and even
    summary.json refused (64 B), scenario.toml refused (1500 B), telemetry.csv's first rows, its rows in
    the warm-up, in the slew. The run ends with status 2 and a message naming the file, no traceback;
    the armed board is disarmed; what could be written is whole lines, what could not is counted in
    summary.json — or, if summary.json itself does not fit, the message names it and no temporary file is
    left."""
    tmp = tmp_path_factory.mktemp("full")
    hil = _spawn(
        tmp,
        "--duration",
        "20",
        "--no-plots",
        preexec_fn=_file_size_limit(limit),
        stdout=subprocess.PIPE,  # pipes: the limit would refuse a file's writes too
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        err = hil.communicate(timeout=300)[1]
    finally:
        if hil.poll() is None:
            hil.kill()
            hil.wait()
    status = hil.returncode
    assert "Traceback" not in err, err
    run_dir = _run_dir(tmp) or next(iter((tmp / "runs").glob("*")), None)
    assert run_dir is not None
    assert status == 2, f"status {status} with a {limit}-byte limit: {err[-2000:]}"
    assert f"hil run: cannot write {run_dir}/" in err and os.strerror(errno.EFBIG) in err
    if not (run_dir / "summary.json").exists():
        assert f"cannot write {run_dir}/summary.json" in err
        assert not list(run_dir.glob("*.tmp"))
        return
    summary = _honest_run_dir(run_dir, logs=False)
    assert summary["exit"].startswith(f"error: cannot write {run_dir}/"), summary["exit"]
    if "telemetry.csv" in summary["exit"]:
        assert summary["telemetry_rows_not_written"] > 0
        tel = read_telemetry(run_dir / "telemetry.csv")
        assert tel.rows + summary["telemetry_rows_not_written"] == summary["control_ticks"]
    events = read_events(run_dir / "events.jsonl")[0] + summary.get("events_not_written", [])
    if "armed" in [e["kind"] for e in events]:
        disarmed = [e for e in events if e["kind"] == "disarmed"]
        assert [e["reason"] for e in disarmed] == [summary["exit"]]


class _SignalsAsItEnds(SilentObserver):
    """A run's observer that signals its own process (``signum``) as the run starts writing its ending
    (``ending``: the summary about to be gathered) — a real signal, in the window that used to lose it."""

    def __init__(self, signum: int) -> None:
        self.signum = signum

    def ending(self, t: float) -> None:
        os.kill(os.getpid(), self.signum)


@pytest.mark.parametrize("report", [True, False], ids=["reported", "raised"])
def test_a_signal_as_a_completed_run_writes_its_ending_is_held_until_it_is_written(tmp_path, report):
    """SIGINT while a run that completed writes its ending: the ending is written whole and says
    ``completed`` (the run did), and then the signal is acted on — reported in ``late_signal`` (``hil
    run``: no plots, status 1) or raised to its handler as it would have been (a campaign stops)."""
    from hil.runtime import RunOptions, run
    from hil.scenario import load_scenario

    opts = RunOptions(
        out_root=tmp_path / "runs",
        duration_s=0.5,
        observer=_SignalsAsItEnds(signal.SIGINT),
        **({"report_late_signal": True} if report else {}),  # the default: raised
    )
    if report:
        result = run(load_scenario("cubesat-1u"), opts)
        assert result.late_signal == "SIGINT" and result.summary["exit"] == "completed"
    else:
        with pytest.raises(KeyboardInterrupt):
            run(load_scenario("cubesat-1u"), opts)
    run_dir = _run_dir(tmp_path)
    assert run_dir is not None
    assert _honest_run_dir(run_dir)["exit"] == "completed"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # its handler given back


EVENTS_ON_A_FULL_DISK = """
import json, resource, sys
from hil.files.output import OutputError
from hil.runtime.runlog import EventLog
resource.setrlimit(resource.RLIMIT_FSIZE, (300, 300))  # Python ignores SIGXFSZ: EFBIG instead
log = EventLog(sys.argv[1])
raised = []
for i in range(20):
    try:
        log.write(i * 0.1, "tick", n=i, text="x" * 20)
    except OutputError as exc:
        raised.append((i, exc.errno))
log.close()  # nothing held back: never raises
print(json.dumps({"raised": raised, "unwritten": [e["n"] for e in log.unwritten]}))
"""


def test_an_events_log_on_a_full_disk_raises_once_and_keeps_the_rest(tmp_path):
    """The events log's write refused (EFBIG, as a full disk's ENOSPC): raised once, as an OutputError
    naming the file, the file cut back to its last whole line; the events after it are kept for the
    summary (``events_not_written``) without raising again, and closing the log does not raise (a
    line-buffered file held the refused line and raised it again from close(), in the run's clean-up)."""
    path = tmp_path / "events.jsonl"
    done = subprocess.run(
        [sys.executable, "-c", EVENTS_ON_A_FULL_DISK, str(path)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    events, bad = read_events(path)
    assert bad == 0 and path.read_bytes().endswith(b"\n")
    first = len(events)
    assert report["raised"] == [[first, errno.EFBIG]]
    assert [e["n"] for e in events] + report["unwritten"] == list(range(20))


def test_a_signal_repeated_while_the_ending_is_written_gives_it_up(tmp_path):
    """Only one signal is held: a second one while the ending is written (a stalled disk, a user pressing
    Ctrl-C again and again) goes to its handler as before — no run is one that only SIGKILL ends."""
    from hil.runtime import RunOptions, run
    from hil.scenario import load_scenario

    class Twice(_SignalsAsItEnds):
        def ending(self, t: float) -> None:
            super().ending(t)  # held
            super().ending(t)  # raised

    opts = RunOptions(out_root=tmp_path / "runs", duration_s=0.5, observer=Twice(signal.SIGINT))
    with pytest.raises(KeyboardInterrupt):
        run(
            load_scenario("cubesat-1u"),
            opts,
        )
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
