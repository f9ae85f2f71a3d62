"""What a run's figures mark with a vertical line: the operator's commands, the manoeuvre's start and end,
and the faults the host saw — so that a jump in a plot (a slew commanded from the ground station, a board
reset) is explained where it happens. The ground station's page marks the same events by the same rules
(``hil/gcs/static/markers.js``)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from matplotlib.axes import Axes

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


def _command_label(event: Mapping[str, Any]) -> str:
    name = str(event.get("command"))
    euler = event.get("target_euler_deg")
    if name == "slew" and isinstance(euler, list) and len(euler) == 3:
        name = "slew to " + "/".join(f"{float(x):g}" for x in euler) + "°"
    label = f"{name} ({event.get('origin', '?')})"
    return f"{label} refused" if event.get("status") == "refused" else label


def run_markers(events: Iterable[Mapping[str, Any]]) -> list[Marker]:
    """The markers of a run's events (``events.jsonl`` records), in time order: each operator command once
    (its first record: ``sent`` or ``applied``/``refused``; a request the server turned away is not a
    command), the slew's start and end, and each fault (a board reset, a link lost, the board failing
    safe, a dead ESC, a phone gap, a silent board)."""
    out: list[Marker] = []
    seen: set[Any] = set()
    for e in events:
        t, kind = e.get("t"), e.get("kind")
        if not isinstance(t, (int, float)):
            continue
        if kind == "command":
            key = (e.get("origin"), e.get("id"))
            if e.get("id") is None or key in seen:
                continue
            seen.add(key)
            out.append(Marker(float(t), _command_label(e), COMMAND))
        elif kind in MANOEUVRE_KINDS:
            out.append(Marker(float(t), MANOEUVRE_KINDS[kind], MANOEUVRE))
        elif kind in FAULT_KINDS:
            out.append(Marker(float(t), FAULT_KINDS[kind], FAULT))
        elif kind == "board_state" and e.get("new") == "FAILSAFE":
            out.append(Marker(float(t), "FAILSAFE", FAULT))
    out.sort(key=lambda m: m.t)
    return out


def draw_markers(ax: Axes, markers: list[Marker]) -> int:
    """A dashed vertical line per marker inside the axes' time range, the first :data:`MAX_LABELS`
    labelled along the line at the top; one legend entry per kind. Returns how many were drawn."""
    lo, hi = ax.get_xlim()
    drawn = 0
    in_legend: set[str] = set()
    for m in markers:
        if not lo <= m.t <= hi:
            continue
        legend = (
            None
            if m.kind in in_legend
            else {COMMAND: "command", MANOEUVRE: "manoeuvre", FAULT: "fault"}[m.kind]
        )
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
