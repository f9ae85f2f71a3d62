"""``hil calibrate``'s options judged before anything is written, and every ``--seed`` bounded.

``hil calibrate fit … -o cal/exist.toml --plot cal/p.xyz`` wrote the calibration file and then failed on the
plot's format (status 2, the file already changed); ``--plot cal/noext`` saved ``cal/noext.png`` and said
``plot cal/noext``. ``hil calibrate bench --seed -1`` was numpy's ValueError traceback, and ``--mirrored 99``
with ``--units 2`` was ignored, unsaid; ``firmware-sim --seed -1`` seeded the Python board as seed 1
(``random.Random(-1)``) and the firmware harness refused it.
"""

from __future__ import annotations

import pytest

from firmware_sim.cli import build_parser as firmware_parser
from firmware_sim.cli import main as firmware_main
from hil.calibration.generate import generate_bench
from hil.cli import main

BAD_SEEDS = ["-1", str(2**64), str(2**64 + 1), "1" + "0" * 40]
FIRMWARE_MAX_SEED = 10**18
"""firmware-sim's largest --seed: the firmware harness's (firmware/harness/main.c)."""


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    generate_bench(out, 2, 3, (1,))
    return out


def _fit(bench, out, *more: str) -> int:
    csvs = [str(bench / f"unit1_{k}.csv") for k in ("rotor", "gimbal_rate", "gimbal_angle")]
    return main(["calibrate", "fit", *csvs, "-o", str(out), "--unit", "1", *more])


@pytest.mark.parametrize("plot", ["p.xyz", "p.txt", "p.toml", "p.png2", "folder.png"])
def test_a_plot_that_cannot_be_saved_is_refused_before_the_calibration_file_changes(
    bench, tmp_path, capsys, plot
):
    out = tmp_path / "cal" / "exist.toml"
    assert _fit(bench, out) == 0
    before = out.read_bytes()
    (tmp_path / "cal" / "folder.png").mkdir()
    capsys.readouterr()
    assert _fit(bench, out, "--unit", "0", "--plot", str(tmp_path / "cal" / plot)) == 2
    err = capsys.readouterr().err
    assert "--plot" in err and "Traceback" not in err
    assert out.read_bytes() == before  # unit 0 not added: nothing written
    assert sorted(p.name for p in (tmp_path / "cal").iterdir()) == [
        "exist-unit1.png",
        "exist.toml",
        "folder.png",
    ]


def test_a_new_calibration_file_is_not_made_for_a_plot_that_cannot_be_saved(bench, tmp_path):
    out = tmp_path / "new.toml"
    assert _fit(bench, out, "--plot", str(tmp_path / "p.xyz")) == 2
    assert not out.exists()


@pytest.mark.parametrize(
    ("plot", "saved"), [("noext", "noext.png"), ("fit.SVG", "fit.SVG"), ("sub/f.pdf", "sub/f.pdf")]
)
def test_the_plot_is_said_where_it_was_saved(bench, tmp_path, capsys, plot, saved):
    assert _fit(bench, tmp_path / "set.toml", "--plot", str(tmp_path / plot)) == 0
    said = capsys.readouterr().out
    assert (tmp_path / saved).is_file()
    assert said.rstrip().endswith(f"plot {tmp_path / saved}")


# --------------------------------------------------------------------------- hil calibrate bench
@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--seed", "-1"], "--seed: must be an integer in 0..9223372036854775807, got -1"),
        (["--seed", str(2**64)], f"--seed: must be an integer in 0..9223372036854775807, got {2**64}"),
        (["--mirrored", "99"], "--mirrored: unit 99 is not one of the bench's units 0..1"),
        (["--mirrored", "0", "-1"], "--mirrored: unit -1 is not one of the bench's units 0..1"),
        (["--mirrored", "2"], "--mirrored: unit 2 is not one of the bench's units 0..1"),
    ],
)
def test_bench_refuses_a_seed_or_a_mirrored_unit_out_of_range(tmp_path, capsys, extra, said):
    assert main(["calibrate", "bench", "--out-dir", str(tmp_path / "b"), "--units", "2", *extra]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()


def test_bench_mirrors_unit_3_by_default_only_where_there_is_one(tmp_path):
    assert main(["calibrate", "bench", "--out-dir", str(tmp_path / "two"), "--units", "2"]) == 0
    assert (
        main(["calibrate", "bench", "--out-dir", str(tmp_path / "four"), "--units", "4", "--seed", "0"]) == 0
    )
    angle = (tmp_path / "four" / "unit3_gimbal_angle.csv").read_text()
    assert angle != (tmp_path / "four" / "unit2_gimbal_angle.csv").read_text()


# --------------------------------------------------------------------------- every --seed
@pytest.mark.parametrize("value", BAD_SEEDS)
@pytest.mark.parametrize(
    "argv",
    [
        ["calibrate", "bench", "--out-dir", "{tmp}/b", "--units", "2", "--seed"],
        ["montecarlo", "cubesat-1u", "--runs", "1", "--out", "{tmp}/mc", "--seed"],
    ],
    ids=["calibrate-bench", "montecarlo"],
)
def test_every_hil_seed_out_of_range_is_a_clear_error(tmp_path, capsys, argv, value):
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main([*args, value]) == 2
    err = capsys.readouterr().err
    assert "--seed: must be an integer in 0.." in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", [*BAD_SEEDS, str(FIRMWARE_MAX_SEED + 1), "x", "1.5"])
def test_firmware_sim_refuses_a_seed_out_of_range(capsys, value):
    with pytest.raises(SystemExit) as exc:
        firmware_main([f"--seed={value}", "--duration", "0.01"])
    assert exc.value.code == 2
    assert f"argument --seed: must be an integer in 0..{FIRMWARE_MAX_SEED}" in capsys.readouterr().err


def test_firmware_sim_takes_every_seed_its_firmware_harness_does():
    """The harness (firmware/harness/main.c) takes 0..1e18: the bound is the same, so one seed seeds
    either board."""
    assert firmware_parser().parse_args([f"--seed={FIRMWARE_MAX_SEED}"]).seed == 10**18
    assert firmware_parser().parse_args(["--seed", "0"]).seed == 0
