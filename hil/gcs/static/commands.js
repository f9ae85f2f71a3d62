// The command history: every operator command of the run up to the cursor (from its "command" events, so a
// replay has it too, whoever sent it — this page, another browser, a script, a fault campaign), one row per
// command with its sender, time, acknowledgement and outcome, and each request the server turned away; and
// its export as CSV.

import { $, fmt, shortText, threeNumbers } from "./panels.js";
import { downloadCsv, safeName } from "./exports.js";

export const HISTORY_COLUMNS = ["id", "t (s)", "sender", "command", "acknowledgement", "outcome"];

function describe(e) {
  const euler = threeNumbers(e.target_euler_deg);
  if (e.command === "slew" && euler) return `slew to roll ${euler[0]}°, pitch ${euler[1]}°, yaw ${euler[2]}°`;
  return e.command === null || e.command === undefined ? "—" : shortText(e.command);
}

function acknowledgement(c) {
  const last = c.last;
  if (last.status === "acked") return `acked by the board${Number.isFinite(last.after_ms) ? ` after ${last.after_ms.toFixed(0)} ms` : ""}`;
  if (last.status === "nacked") return `nacked by the board${last.reason ? `: ${shortText(last.reason)}` : ""}`;
  if (last.status === "failed") return "no answer from the board";
  if (last.status === "superseded") return "superseded by a newer command before the board answered";
  if (last.status === "applied") return "applied by the host";
  if (last.status === "refused") return "refused by the host";
  if (last.status === "sent") return "waiting for the board";
  return "—";
}

function outcome(c) {
  const last = c.last;
  const why = last.reason ? `: ${shortText(last.reason)}` : "";
  if (last.status === "acked" || last.status === "applied") return "done";
  if (last.status === "rejected") return `rejected${why}${last.detail ? ` (${shortText(last.detail)})` : ""}`;
  if (last.status === "sent") return "pending";
  return `${shortText(last.status)}${why}`;
}

// The history at time t: [{id, t, sender, command, acknowledgement, outcome, status}], oldest first.
export function commandHistory(events, t) {
  const byId = new Map(), out = [];
  for (const e of events) {
    if (e.t > t) break;
    if (e.kind !== "command") continue;
    if (e.id === null || e.id === undefined) {  // a request turned away: its own row
      out.push({ first: e, last: e });
      continue;
    }
    const key = JSON.stringify([e.origin, e.id]);  // objects too, each its own (a template made all "[object Object]")
    const c = byId.get(key);
    if (c) { c.last = e; continue; }
    const entry = { first: e, last: e };
    byId.set(key, entry);
    out.push(entry);
  }
  return out.map((c) => ({
    id: c.first.id ?? "", t: c.first.t,
    sender: [c.first.origin, c.first.remote].filter(Boolean).map(shortText).join(" "),
    command: describe(c.first), acknowledgement: acknowledgement(c), outcome: outcome(c), status: c.last.status,
  }));
}

let shownKey = "";

export function drawHistory(events, t) {
  const rows = commandHistory(events, t);
  const key = JSON.stringify(rows.map((r) => [r.id, r.status]));
  if (key === shownKey) return;
  shownKey = key;
  const body = document.querySelector("#cmd-history tbody");
  body.innerHTML = "";
  for (const r of rows.slice().reverse()) {
    const tr = document.createElement("tr");
    tr.dataset.id = shortText(r.id);
    tr.dataset.status = shortText(r.status);
    for (const v of [r.id, fmt(r.t, 2), r.sender, r.command, r.acknowledgement, r.outcome]) {
      const td = document.createElement("td");
      td.textContent = shortText(v);
      tr.appendChild(td);
    }
    body.appendChild(tr);
  }
  $("cmd-history-count").textContent = `(${rows.length})`;
}

export function exportHistory(events, t, run) {
  const rows = commandHistory(events, t).map((r) => [r.id, r.t, r.sender, r.command, r.acknowledgement, r.outcome]);
  downloadCsv(`${safeName(run)}-commands.csv`, HISTORY_COLUMNS, rows);
}
