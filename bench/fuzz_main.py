"""The command line the atheris harnesses (``bench/fuzz_deframer.py``, ``bench/fuzz_phone.py``) share:
libFuzzer's options and corpus directories from ``argv``, plus a fresh directory of the harness's seed
inputs. Imported by the harness scripts from their own directory (they run as scripts, from any cwd)."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import atheris


def run_fuzzer(
    argv: list[str], seeds: list[bytes], test_one_input: Callable[[bytes], None], prefix: str
) -> None:
    """Fuzz ``test_one_input`` from ``seeds`` (written to a new temporary directory named ``prefix…``)
    and the corpus directories in ``argv``: libFuzzer writes new inputs to the first corpus directory and
    reads seeds from all of them."""
    corpus = [a for a in argv[1:] if not a.startswith("-")]
    seed_dir = Path(tempfile.mkdtemp(prefix=prefix))
    for i, data in enumerate(seeds):
        (seed_dir / f"seed-{i:04d}").write_bytes(data)
    args = [argv[0], *[a for a in argv[1:] if a.startswith("-")], *corpus, str(seed_dir)]
    atheris.Setup(args, test_one_input)
    atheris.Fuzz()
