// What the plots mark with a vertical line: each operator command once (its first record), the slew's start
// and end, and the faults the host saw — the rules of hil/plots/markers.py, which marks the saved figures.

import { shortText, threeNumbers } from "./panels.js";

export const MARKER_COLORS = { command: "#1f5fbf", manoeuvre: "#6b7480", fault: "#c62828" };
const FAULT_KINDS = { board_reset: "board reset", link_lost: "link lost", esc_dead: "ESC dead", phone_gap: "phone gap", silence: "board silent", phone_switch: "phone switched" };
const MANOEUVRE_KINDS = { slew_start: "slew start", slew_end: "slew end" };

function commandLabel(e) {
  let name = shortText(e.command);
  const euler = threeNumbers(e.target_euler_deg);
  if (name === "slew" && euler) name = `slew to ${euler.join("/")}°`;
  const label = `${name} (${shortText(e.origin ?? "?")})`;
  return e.status === "refused" ? `${label} refused` : label;
}

// The markers of events (in time order, as the store holds them): [{t, label, kind}]. A kind is looked up
// among the tables' own names only: `in` also found the prototype's, and a record of kind "constructor"
// (a run directory's events are any JSON) was marked on every plot as "function Object() { [native code] }".
export function runMarkers(events) {
  const out = [], seen = new Set();
  for (const e of events) {
    if (!Number.isFinite(e.t)) continue;
    if (e.kind === "command") {
      if (e.id === null || e.id === undefined) continue;
      const key = JSON.stringify([e.origin, e.id]);  // objects too, each its own (a template made all "[object Object]")
      if (seen.has(key)) continue;
      seen.add(key);
      out.push({ t: e.t, label: commandLabel(e), kind: "command" });
    } else if (Object.hasOwn(MANOEUVRE_KINDS, e.kind)) out.push({ t: e.t, label: MANOEUVRE_KINDS[e.kind], kind: "manoeuvre" });
    else if (Object.hasOwn(FAULT_KINDS, e.kind)) out.push({ t: e.t, label: FAULT_KINDS[e.kind], kind: "fault" });
    else if (e.kind === "board_state" && e.new === "FAILSAFE") out.push({ t: e.t, label: "FAILSAFE", kind: "fault" });
  }
  return out;
}

// A uPlot plugin drawing getMarkers() as dashed vertical lines with their labels along them; the ones drawn
// are listed in the plot's data-markers ("t label;..."), which the tests read.
export function markerPlugin(getMarkers, box) {
  return {
    hooks: {
      draw: [(u) => {
        const { ctx, bbox } = u;
        const [lo, hi] = [u.scales.x.min, u.scales.x.max];
        const drawn = [];
        ctx.save();
        ctx.font = `${Math.round(10 * devicePixelRatio)}px system-ui, sans-serif`;
        ctx.setLineDash([5 * devicePixelRatio, 4 * devicePixelRatio]);
        ctx.lineWidth = devicePixelRatio;
        for (const m of getMarkers()) {
          if (!(m.t >= lo && m.t <= hi)) continue;
          const x = Math.round(u.valToPos(m.t, "x", true));
          ctx.strokeStyle = ctx.fillStyle = MARKER_COLORS[m.kind];
          ctx.beginPath(); ctx.moveTo(x, bbox.top); ctx.lineTo(x, bbox.top + bbox.height); ctx.stroke();
          ctx.save();
          ctx.translate(x - 3 * devicePixelRatio, bbox.top + 4 * devicePixelRatio);
          ctx.rotate(-Math.PI / 2);
          ctx.textAlign = "right";
          ctx.fillText(m.label, 0, 0);
          ctx.restore();
          drawn.push(`${m.t} ${m.label}`);
        }
        ctx.restore();
        box.dataset.markers = drawn.join(";");
      }],
    },
  };
}
