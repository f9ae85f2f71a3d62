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
  // Two commands are superseded: one sent to the board, a newer one setting the same thing before its answer
  // came (the board's, hil/runtime/operator.py _settle), and an operator's hold or slew the host deferred,
  // a newer target taking its place before its slew started (_settle_deferred) — never sent to the board.
  // The second read "superseded … before the board answered", of a board that was never asked.
  if (last.status === "superseded") {
    return c.sent ? "superseded by a newer command before the board answered"
      : `superseded before its slew started${last.reason ? `: ${shortText(last.reason)}` : ""}`;
  }
  if (last.status === "deferred") return `deferred by the host${last.reason ? `: ${shortText(last.reason)}` : ""}`;
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
  if (last.status === "sent" || last.status === "deferred") return "pending";
  return `${shortText(last.status)}${why}`;
}

// The command events of a store's events, scanned once each: the store appends events that come in time
// order to the same array and merges a batch out of order into a new one (store.js, pushEvents), so only a
// new array (or a shorter one) is scanned afresh. Before, every redraw walked all of the run's events.
// app.js's targetAt reads the ground commands' targets through it too (it walked every event each frame).
const scanned = { events: null, n: 0, commands: [] };
export function commandEvents(events) {
  if (scanned.events !== events || events.length < scanned.n) Object.assign(scanned, { events, n: 0, commands: [] });
  for (let i = scanned.n; i < events.length; i++) if (events[i].kind === "command") scanned.commands.push(events[i]);
  scanned.n = events.length;
  return scanned.commands;
}

// The commands at time t, oldest first: {first, last, sent} per command (its first and last steps, and
// whether it went to the board), and a request turned away its own.
function historyEntries(events, t) {
  const byId = new Map(), out = [];
  for (const e of commandEvents(events)) {
    if (e.t > t) break;
    if (e.id === null || e.id === undefined) {  // a request turned away: its own row
      out.push({ first: e, last: e, sent: false });
      continue;
    }
    const key = JSON.stringify([e.origin, e.id]);  // objects too, each its own (a template made all "[object Object]")
    const c = byId.get(key);
    if (c) { c.last = e; c.sent = c.sent || e.status === "sent"; continue; }
    const entry = { first: e, last: e, sent: e.status === "sent" };
    byId.set(key, entry);
    out.push(entry);
  }
  return out;
}

function rowOf(c) {
  return {
    id: c.first.id ?? "", t: c.first.t,
    sender: [c.first.origin, c.first.remote].filter(Boolean).map(shortText).join(" "),
    command: describe(c.first), acknowledgement: acknowledgement(c), outcome: outcome(c), status: c.last.status,
  };
}

// The history at time t: [{id, t, sender, command, acknowledgement, outcome, status}], oldest first.
export function commandHistory(events, t) {
  return historyEntries(events, t).map(rowOf);
}

// The table shows the newest SHOWN_MAX commands (the export has them all), and a redraw touches only the
// rows that changed: each row's <tr> is kept, keyed by its command's first step. Before, the whole table was
// rebuilt on every status of every command — a long run's history, thousands of rows, redrawn for each.
export const SHOWN_MAX = 300;
const drawn = new Map();  // a row's first event → { tr, shows: its cells' text }

export function drawHistory(events, t) {
  const entries = historyEntries(events, t);
  const shown = entries.slice(-SHOWN_MAX).reverse();  // newest first
  const body = document.querySelector("#cmd-history tbody");
  const keep = new Set(shown.map((c) => c.first));
  for (const [first, d] of drawn) if (!keep.has(first)) { d.tr.remove(); drawn.delete(first); }
  let at = body.firstChild;
  for (const c of shown) {
    const r = rowOf(c);
    const cells = [r.id, fmt(r.t, 2), r.sender, r.command, r.acknowledgement, r.outcome].map(shortText);
    const shows = JSON.stringify([cells, r.status]);
    let d = drawn.get(c.first);
    if (!d) {
      d = { tr: document.createElement("tr"), shows: "" };
      drawn.set(c.first, d);
    }
    if (d.shows !== shows) {
      d.shows = shows;
      d.tr.dataset.id = cells[0];
      d.tr.dataset.status = shortText(r.status);
      d.tr.replaceChildren(...cells.map((v) => { const td = document.createElement("td"); td.textContent = v; return td; }));
    }
    if (d.tr === at) at = at.nextSibling;
    else body.insertBefore(d.tr, at);
  }
  const count = entries.length > shown.length ? `(${entries.length}; the newest ${shown.length} shown, the export has all)` : `(${entries.length})`;
  const countEl = $("cmd-history-count");
  if (countEl.textContent !== count) countEl.textContent = count;
}

export function exportHistory(events, t, run) {
  const rows = commandHistory(events, t).map((r) => [r.id, r.t, r.sender, r.command, r.acknowledgement, r.outcome]);
  downloadCsv(`${safeName(run)}-commands.csv`, HISTORY_COLUMNS, rows);
}
