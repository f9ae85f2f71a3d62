"""Where ``hil run`` makes its run directory, beside the names tested before (a hunt's findings), through the
real command and the real file system:

1. a scenario named in letters of four bytes each (a CJK letter of Unicode's extension B, ``𠀀``; ``𝐀``): the
   label cut to 64 letters was 256 bytes, the run directory's name 272 — "File name too long", status 2,
   for a valid scenario; the label is now cut to fit a file name, in whole letters;
2. ``--out`` through something that is there but no directory — a link to nothing, a loop of links, a
   file, a FIFO, a device: "a file of that name exists" said of the run directory (no file of that name
   anywhere) or "Not a directory", naming neither the part in the way nor what it is; now both;
3. a run directory's name taken by a link to nothing (or a file) in the runs folder: the run was refused
   ("a file of that name exists") where a name taken by a directory moves on to the next ``-n``; now any
   name taken moves on.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.files.output import safe_label
from hil.runtime.runlog import new_run_dir

NAME_MAX = 255  # bytes of one file name (Linux's file systems)


def _hil_run(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "run", "--duration", "0.5", "--no-plots", *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        encoding="utf-8",
        errors="backslashreplace",
        timeout=300,
    )


def _scenario_named(tmp_path: Path, name: str) -> Path:
    shipped = Path(__file__).resolve().parents[1] / "fixtures" / "scenarios" / "cubesat-1u.toml"
    lines = shipped.read_text(encoding="utf-8").splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("name = "))
    lines[at] = f"name = {json.dumps(name, ensure_ascii=False)}"
    path = tmp_path / "named.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


@pytest.mark.parametrize("name", ["\U00020000" * 70, "cubesat-" + "\U0001d400" * 80])
def test_a_scenario_named_in_four_byte_letters_runs_in_a_directory_the_disk_can_name(tmp_path, name):
    done = _hil_run("--scenario", str(_scenario_named(tmp_path, name)), "--out", "runs", cwd=tmp_path)
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.returncode == 0, done.stderr[-2000:]
    (run_dir,) = (tmp_path / "runs").iterdir()
    assert len(os.fsencode(run_dir.name)) <= NAME_MAX
    assert json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))["exit"] == "completed"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(label=st.text(min_size=0, max_size=300), taken=st.integers(0, 3))
def test_any_label_makes_a_run_directory_whatever_names_are_taken(tmp_path, label, taken):
    """On the real file system: a label of any letters (of 1-4 bytes, any number of them) gives a run
    directory, fresh, however many of its names are taken already (each taken as a directory, a file, a
    link to nothing in turn) — never "File name too long", never a taken one."""
    root = tmp_path / f"root-{time.monotonic_ns()}"
    root.mkdir()
    first = new_run_dir(root, label)
    assert len(os.fsencode(first.name)) <= NAME_MAX - len("-9999")
    assert safe_label(label) in first.name
    first.rmdir()
    planted = []
    for n in range(1, taken + 1):  # the names the next run would take, planted as something else
        spot = first if n == 1 else first.with_name(f"{first.name}-{n}")
        [spot.mkdir, spot.touch, lambda s=spot: s.symlink_to(root / "nothing")][n % 3]()
        planted.append(spot)
    made = new_run_dir(root, label)
    assert made.is_dir() and not made.is_symlink() and made not in planted and not any(made.iterdir())


@pytest.fixture
def in_the_way(tmp_path):
    """Things that are there and are no directory: (name, how to plant it, what the error calls it)."""
    return {
        "dangling": (lambda p: p.symlink_to(tmp_path / "gone"), "a symbolic link to nothing"),
        "loop": (
            lambda p: (p.symlink_to(p.with_name("loop2")), p.with_name("loop2").symlink_to(p)),
            "a loop of symbolic links",
        ),
        "file": (lambda p: p.write_text("x"), "a file"),
        "fifo": (lambda p: os.mkfifo(p), "a FIFO"),
    }


@pytest.mark.parametrize("kind", ["dangling", "loop", "file", "fifo", "device"])
def test_out_through_something_that_is_no_directory_is_refused_naming_it(tmp_path, in_the_way, kind):
    """``--out PART/runs`` with PART in the way: status 2, the message names PART and what it is."""
    if kind == "device":
        part, what = Path("/dev/full"), "a device"
    else:
        plant, what = in_the_way[kind]
        part = tmp_path / kind
        plant(part)
    done = _hil_run("--out", str(part / "runs"), cwd=tmp_path)
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.returncode == 2, done.stderr[-2000:]
    assert f"{part} is {what}" in done.stderr, done.stderr[-2000:]


def test_a_run_directory_name_taken_by_a_link_to_nothing_moves_on_to_the_next(tmp_path):
    """The names a run started in the next two minutes would take, each a link to nothing: the run
    completes in the next name (``-2``), the links left as they were."""
    runs = tmp_path / "runs"
    runs.mkdir()
    now = time.time()
    links = []
    for s in range(-2, 120):
        link = runs / f"{time.strftime('%Y%m%d-%H%M%S', time.localtime(now + s))}-cubesat-1u"
        link.symlink_to(tmp_path / "nothing")
        links.append(link)
    done = _hil_run("--out", "runs", cwd=tmp_path)
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.returncode == 0, done.stderr[-2000:]
    (run_dir,) = [p for p in runs.iterdir() if not p.is_symlink()]
    assert run_dir.name.endswith("-cubesat-1u-2")
    assert json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))["exit"] == "completed"
    assert all(link.is_symlink() and not link.exists() for link in links)


@pytest.mark.parametrize("letter", ["a", "é", "𝐀"])
def test_a_replay_of_a_log_with_a_name_near_the_limit_writes_its_default_folder(tmp_path, letter):
    """``hil replay LOG`` writes to ``runs/replay-<log name>``: a log named with 249 or more bytes (a
    name the file system holds) made a folder name past 255 bytes, "File name too long". The name is cut,
    in whole letters, to fit."""
    log = (
        Path(__file__).resolve().parents[2]
        / "shared"
        / "data"
        / "broad"
        / "01_undisturbed_slow_rotation_A.mat"
    )
    if not log.is_file():
        pytest.skip(f"the shared data is not beside the project: {log}")
    stem = letter * ((255 - len(".mat")) // len(letter.encode()))
    named = tmp_path / f"{stem}.mat"
    named.write_bytes(log.read_bytes())  # a copy: a link's name is resolved to its target's
    done = subprocess.run(
        [sys.executable, "-m", "hil", "replay", named.name, "--no-plots", "--window", "0", "20"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    (folder,) = (tmp_path / "runs").iterdir()
    assert folder.name.startswith(f"replay-{letter}") and len(os.fsencode(folder.name)) <= 255
    assert (folder / "summary.json").is_file() and (folder / "estimates.csv").is_file()


@pytest.mark.parametrize("letter", ["a", "é", "𝐀"])
def test_a_file_named_near_the_limit_is_replaced_whole(tmp_path, letter):
    """Every output is written beside its file and renamed over it: the temporary name took 64 letters
    of the file's name, and 64 four-byte letters with mkstemp's additions passed 255 bytes — a file the
    file system holds could not be written ("File name too long")."""
    from hil.files.output import replace_file

    name = letter * ((255 - len(".png")) // len(letter.encode())) + ".png"
    target = tmp_path / name
    for content in (b"first", b"second"):
        replace_file(target, lambda f, content=content: f.write(content))
        assert target.read_bytes() == content
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary file left
