"""What a run's figures mark with a vertical line: the operator's commands, the manoeuvre's start and end,
and the faults the host saw — so that a jump in a plot (a slew commanded from the ground station, a board
reset) is explained where it happens. The ground station's page marks the same events by the same rules
(``hil/gcs/static/markers.js``)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from matplotlib.axes import Axes

from hil.numbers import is_finite_number

COMMAND, MANOEUVRE, FAULT = "command", "manoeuvre", "fault"
COLORS = {COMMAND: "#1f5fbf", MANOEUVRE: "#6b7480", FAULT: "#c62828"}
"""The line's colour by kind (the page's: commands blue, faults red, the manoeuvre grey)."""
MAX_LABELS = 12
"""Lines labelled at most per figure (the first ones); more are drawn unlabelled, counted in the legend."""

FAULT_KINDS = {
    "board_reset": "board reset",
    "link_lost": "link lost",
    "esc_dead": "ESC dead",
    "phone_gap": "phone gap",
    "silence": "board silent",
    "phone_switch": "phone switched",  # another phone followed: the estimate starts afresh
}
MANOEUVRE_KINDS = {"slew_start": "slew start", "slew_end": "slew end"}


@dataclass(frozen=True)
class Marker:
    t: float  # s, run time
    label: str
    kind: str  # COMMAND, MANOEUVRE or FAULT


MAX_PER_KIND = 200
"""Markers kept (and drawn) at most per kind: the first ones; the rest are counted in the legend (20 000
commands drew 20 000 lines per figure: 81 s and 381 MB for one run's figures)."""
MAX_LABEL = 60
"""Characters of a marker's label at most (a command's name is whatever its event says)."""
MAX_SEEN = 10_000
"""Commands remembered at most to mark each once (its first record); past them a command's further
records are counted as more, not remembered."""
_LEGEND = {COMMAND: "command", MANOEUVRE: "manoeuvre", FAULT: "fault"}


class Markers(list[Marker]):
    """A run's markers (:func:`run_markers`), in time order, with what was left out: ``more`` per kind
    (beyond :data:`MAX_PER_KIND`) and ``malformed`` — command records whose time, origin or id is not
    what a run writes (a bool, a list, an object, a non-finite time), skipped."""

    def __init__(self, markers: Iterable[Marker] = (), more: Mapping[str, int] | None = None) -> None:
        super().__init__(markers)
        self.more: dict[str, int] = dict(more or {})
        self.malformed = 0


def _key(x: object) -> bool:
    """An origin or id a run writes: a string or an integer (a list or an object cannot be told apart)."""
    return isinstance(x, (str, int)) and not isinstance(x, bool)


def _command_label(event: Mapping[str, Any]) -> str:
    name = str(event.get("command"))[:MAX_LABEL]
    euler = event.get("target_euler_deg")
    if name == "slew" and isinstance(euler, list) and len(euler) == 3 and all(map(is_finite_number, euler)):
        name = "slew to " + "/".join(f"{float(x):g}" for x in euler) + "°"
    label = f"{name} ({str(event.get('origin', '?'))[:MAX_LABEL]})"
    return f"{label} refused" if event.get("status") == "refused" else label


def run_markers(events: Iterable[Mapping[str, Any]]) -> Markers:
    """The markers of a run's events (``events.jsonl`` records, streamed: only the markers are kept), in
    time order: each operator command once (its first record: ``sent`` or ``applied``/``refused``; a
    request the server turned away is not a command), the slew's start and end, and each fault (a board
    reset, a link lost, the board failing safe, a dead ESC, a phone gap, a silent board). An event whose
    time is not a finite number (``true``, NaN) is no marker; a command whose origin or id is not a string
    or an integer is skipped, counted (:attr:`Markers.malformed`); past :data:`MAX_PER_KIND` of a kind
    they are counted (:attr:`Markers.more`)."""
    out = Markers()
    seen: set[tuple[object, object]] = set()
    kept = dict.fromkeys(_LEGEND, 0)

    def add(t: float, label: str, kind: str) -> None:
        if kept[kind] < MAX_PER_KIND:
            kept[kind] += 1
            out.append(Marker(t, label, kind))
        else:
            out.more[kind] = out.more.get(kind, 0) + 1

    for e in events:
        t, kind = e.get("t"), e.get("kind")
        if kind == "command":
            origin, ident = e.get("origin"), e.get("id")
            if ident is None:  # a request the server turned away
                continue
            if not (is_finite_number(t) and _key(ident) and (origin is None or _key(origin))):
                out.malformed += 1
                continue
            key = (origin, ident)
            if key in seen:
                continue
            if len(seen) < MAX_SEEN:
                seen.add(key)
            add(float(t), _command_label(e), COMMAND)  # type: ignore[arg-type]
        elif not is_finite_number(t):
            continue
        elif kind in MANOEUVRE_KINDS:
            add(float(t), MANOEUVRE_KINDS[kind], MANOEUVRE)  # type: ignore[arg-type]
        elif kind in FAULT_KINDS:
            add(float(t), FAULT_KINDS[kind], FAULT)  # type: ignore[arg-type]
        elif kind == "board_state" and e.get("new") == "FAILSAFE":
            add(float(t), "FAILSAFE", FAULT)  # type: ignore[arg-type]
    out.sort(key=lambda m: m.t)
    return out


def draw_markers(ax: Axes, markers: list[Marker]) -> int:
    """A dashed vertical line per marker inside the axes' time range — at most :data:`MAX_PER_KIND` per
    kind, the rest (and a :class:`Markers`' ``more``) counted in the legend — the first :data:`MAX_LABELS`
    labelled along the line at the top; one legend entry per kind. Returns how many were drawn."""
    lo, hi = ax.get_xlim()
    drawn = 0
    per_kind = dict.fromkeys(_LEGEND, 0)
    more = dict(getattr(markers, "more", {}))
    lines: list[Marker] = []
    for m in markers:
        if not lo <= m.t <= hi:
            continue
        if per_kind[m.kind] >= MAX_PER_KIND:
            more[m.kind] = more.get(m.kind, 0) + 1
            continue
        per_kind[m.kind] += 1
        lines.append(m)
    in_legend: set[str] = set()
    for m in lines:
        legend = None
        if m.kind not in in_legend:
            legend = _LEGEND[m.kind] + (f" (+{more[m.kind]} not drawn)" if more.get(m.kind) else "")
        in_legend.add(m.kind)
        ax.axvline(m.t, color=COLORS[m.kind], ls="--", lw=1.0, label=legend)
        if drawn < MAX_LABELS:
            ax.text(
                m.t,
                0.98,
                f" {m.label}",
                transform=ax.get_xaxis_transform(),
                rotation=90,
                va="top",
                ha="right",
                fontsize="x-small",
                color=COLORS[m.kind],
            )
        drawn += 1
    ax.set_xlim(lo, hi)
    return drawn
