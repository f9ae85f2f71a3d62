"""Where the project's own data lives (the checkout is installed in editable mode)."""

from __future__ import annotations

from pathlib import Path

from hil.files.bounded import FOLDER, input_kind, read_document
from protocol.errors import ConfigError, HilError

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
SHARED_DATA = ROOT.parent / "shared" / "data"
"""Real recorded sensor data (read-only, beside the checkout; see its README)."""


def read_text(
    path: Path, error: type[HilError] = ConfigError, what: str = "", limit: int | None = None
) -> str:
    """A text file the project reads (scenario, dispersions, a run directory's files) as UTF-8, at most
    ``limit`` bytes (None: no limit, for a file bounded by how it is used, e.g. a campaign's results); an
    unreadable, binary or larger one is one ``error`` naming the file, never a traceback
    (:func:`hil.files.bounded.read_document`)."""
    return read_document(path, error, what, limit)  # type: ignore[arg-type]


def resolve_named_file(name_or_path: str | Path, directory: Path, what: str, where: str) -> Path:
    """A TOML file the project reads by name or path (a scenario, a dispersion file): ``name_or_path`` as
    given when it ends in ``.toml`` or is there — a regular file, or a pipe (a shell's ``<(…)``: read once)
    —, else the file of that name shipped in ``directory``. A path that is not there, a folder, a device or
    a socket is a :class:`ConfigError` naming it and saying which (:func:`hil.files.bounded.input_kind`); a
    name not shipped one at ``where`` listing the shipped names. ``what`` names the kind of file in
    messages. One rule for both kinds: a dispersion file given as ``<(…)``, a folder or ``/dev/tty`` was
    "no such dispersion file", though it was there and a scenario given so was read."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise ConfigError(f"no such {what} file", str(p))
        if input_kind(p, ConfigError, what) == FOLDER:  # a device or a socket raises there
            raise ConfigError(f"a folder, not a {what} file", str(p))
        return p
    shipped = directory / f"{name_or_path}.toml"
    if not shipped.is_file():
        names = ", ".join(sorted(q.stem for q in directory.glob("*.toml")))
        raise ConfigError(f"no {what} {str(name_or_path)!r}; shipped: {names}", where)
    return shipped
