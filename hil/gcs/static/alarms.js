// Limits and alarms: the run's per-channel limits (info.alarms, from hil/gcs/alarms.py) checked on every
// row the page receives — before the store, whose decimation of a long run must not hide a short excursion
// — into a list of occurrences (raised, cleared, peak, acknowledged), and the panel that lists them with an
// Acknowledge button (POST /api/ack; the acknowledgement comes back as the run's "alarm_ack" event, so a
// replay shows who acknowledged what, and when). An alarm of op "event" has no threshold: the run's
// raise_on event raises it and its clear_on event clears it (another phone on the phone's port).

import { $, fmt, shortText } from "./panels.js";

const SEVERITY_RANK = { critical: 2, warning: 1 };
const MATCH_T = 1e-6;  // s: an acknowledgement's raised_t names the occurrence raised at that time
const SHOWN = 100;     // occurrences listed at most (the newest)
// alarm_ack events kept waiting for their occurrence at most (an acknowledgement can come before the row
// that raises it): past it the oldest waiting go, counted (acksDropped) and said beside the alarm count.
// Unbounded, a flood of acknowledgements naming no alarm (a hostile or corrupt events.jsonl, a client
// POSTing in a loop) grew the page's memory, and every batch of events matched all of them again.
export const MAX_WAITING_ACKS = 1000;
// occurrences kept at most: past it the oldest cleared ones go (down to 3/4 of it at a time, each drop a
// copy, so rarely; an active one is never dropped), counted (occurrencesDropped, occurrencesFrom: the time
// the oldest kept was raised) and said beside the alarm count. Unbounded, a long run's flapping alarm or
// an events.jsonl flooded with raise/clear pairs (phone_other, phone_others_quiet) grew the page's memory
// by every occurrence, and every acknowledgement was matched against all of them.
export const MAX_OCCURRENCES = 20000;

function outside(limit, v) {
  if (limit.op === "above") return v > limit.value;
  if (limit.op === "below") return v < limit.value;
  if (limit.op === "abs_above") return Math.abs(v) > limit.value;
  return v === limit.value;  // equals: a state code
}

function backInside(limit, v) {
  if (limit.op === "above") return v <= limit.clear;
  if (limit.op === "below") return v >= limit.clear;
  if (limit.op === "abs_above") return Math.abs(v) <= limit.clear;
  return v !== limit.value;
}

// How far past its limit a value went: the largest (|v| for abs_above), or the smallest for "below".
function worse(limit, a, b) {
  if (!Number.isFinite(a)) return b;
  if (limit.op === "below") return Math.min(a, b);
  if (limit.op === "abs_above") return Math.abs(b) > Math.abs(a) ? b : a;
  return Math.max(a, b);
}

export class Alarms {
  constructor(info) {
    const index = Object.fromEntries(info.columns.map((c, i) => [c, i]));
    // phases: the run phases (telemetry's phase column, hil/runtime/phases.py) a limit holds in, as a set
    // (hil/gcs/alarms.py always lists them; a limit without the list would hold in every phase)
    this.limits = (info.alarms || []).filter((l) => l.op !== "event" && l.column in index)
      .map((l) => ({ ...l, i: index[l.column], inPhase: Array.isArray(l.phases) ? new Set(l.phases) : null }));
    this.eventLimits = (info.alarms || []).filter((l) => l.op === "event");
    this.phaseIndex = index.phase;
    this.active = new Map();  // key -> the occurrence not yet cleared
    this.list = [];           // every occurrence, in the order raised
    this.acks = [];           // alarm_ack events not yet matched to an occurrence (MAX_WAITING_ACKS at most)
    this.acksDropped = 0;     // alarm_ack events that matched no occurrence, dropped past MAX_WAITING_ACKS
    this.occurrencesDropped = 0;      // the oldest cleared occurrences dropped past MAX_OCCURRENCES
    this.occurrencesFrom = -Infinity;  // when the oldest occurrence kept was raised, once some were dropped
    this.version = 0;         // bumped on every change (the panel redraws only then)
  }

  // Telemetry rows as they come (arrays in info.columns order, null: no value).
  feed(rows) {
    for (const row of rows) {
      const t = row[0];
      const phase = this.phaseIndex === undefined ? null : row[this.phaseIndex];
      for (const limit of this.limits) {
        const v = row[limit.i];
        if (v === null || v === undefined || !Number.isFinite(v)) continue;  // no value: no news
        // a row in a phase the limit does not hold in (a row without a phase is checked)
        if (limit.inPhase && Number.isFinite(phase) && !limit.inPhase.has(phase)) continue;
        const open = this.active.get(limit.key);
        if (!open) {
          if (!outside(limit, v)) continue;
          const occurrence = { key: limit.key, limit, raised_t: t, cleared_t: null, peak: v, ack: null };
          this.active.set(limit.key, occurrence);
          this.list.push(occurrence);
          this.boundList();
          this.matchAcks();
          this.version += 1;
        } else {
          open.peak = worse(limit, open.peak, v);
          if (backInside(limit, v)) { open.cleared_t = t; this.active.delete(limit.key); this.version += 1; }
        }
      }
    }
  }

  // The run's events: an "alarm_ack" marks the occurrence it names as acknowledged; an event alarm's
  // raise_on event raises it (its peak: the most other phones heard, the event's other_phones), its
  // clear_on event clears it.
  onEvents(events) {
    let any = false;
    for (const e of events) {
      if (e.kind === "alarm_ack") { this.acks.push(e); any = true; }
      for (const limit of this.eventLimits) {
        const open = this.active.get(limit.key);
        const count = Number.isFinite(e.other_phones) ? e.other_phones : NaN;
        if (e.kind === limit.raise_on) {
          if (open) { open.peak = worse(limit, open.peak, count); continue; }
          const occurrence = { key: limit.key, limit, raised_t: e.t, cleared_t: null, peak: count, ack: null };
          this.active.set(limit.key, occurrence);
          this.list.push(occurrence);
          this.boundList();
          any = true;
          this.version += 1;
        } else if (e.kind === limit.clear_on && open) {
          open.cleared_t = e.t;
          this.active.delete(limit.key);
          this.version += 1;
        }
      }
    }
    if (any) this.matchAcks();
  }

  // Past MAX_OCCURRENCES, the oldest cleared occurrences go (down to 3/4 of it), counted.
  boundList() {
    if (this.list.length <= MAX_OCCURRENCES) return;
    let drop = this.list.length - Math.floor(MAX_OCCURRENCES * 3 / 4);
    const kept = [];
    for (const o of this.list) {
      if (drop > 0 && o.cleared_t !== null) { drop -= 1; this.occurrencesDropped += 1; } else kept.push(o);
    }
    this.list = kept;
    this.occurrencesFrom = kept.length ? kept[0].raised_t : Infinity;
    this.version += 1;
  }

  matchAcks() {
    const left = [];
    for (const e of this.acks) {
      const o = this.list.find((x) => x.key === e.alarm && Math.abs(x.raised_t - e.raised_t) < MATCH_T);
      if (o) { if (!o.ack) { o.ack = e; this.version += 1; } } else left.push(e);
    }
    // the oldest waiting go first: an acknowledgement follows the row that raised its alarm, so the newest
    // are the ones an occurrence still to come (its row not yet received) may claim
    const over = left.length - MAX_WAITING_ACKS;
    if (over > 0) { left.splice(0, over); this.acksDropped += over; this.version += 1; }
    this.acks = left;
  }

  // The occurrences raised by time t, newest first, each with whether it is active at t.
  at(t) {
    const out = [];
    for (let k = this.list.length - 1; k >= 0 && out.length < SHOWN; k--) {
      const o = this.list[k];
      if (o.raised_t > t) continue;
      const cleared = o.cleared_t !== null && o.cleared_t <= t;
      out.push({ o, active: !cleared, acked: Boolean(o.ack && o.ack.t <= t) });
    }
    return out;
  }

  // Per column, the worst severity of an alarm active at t (the panels colour those cells).
  activeColumns(t) {
    const out = {};
    for (const { o, active } of this.at(t)) {
      if (!active) continue;
      const s = o.limit.severity;
      if (!out[o.limit.column] || SEVERITY_RANK[s] > SEVERITY_RANK[out[o.limit.column]]) out[o.limit.column] = s;
    }
    return out;
  }
}

// A unit after a number: "°" for degrees, else " V", " ms", ...
function unitText(unit) {
  return unit === "deg" ? "°" : unit ? ` ${unit}` : "";
}

function limitText(l) {
  const unit = unitText(l.unit);
  if (l.op === "equals") return "FAILSAFE";
  if (l.op === "event") return "streaming to this port";
  const sign = { above: ">", below: "<", abs_above: "|x| >" }[l.op];
  return `${sign} ${fmt(l.value, l.value >= 100 ? 0 : 2)}${unit}`;
}

function peakText(o) {
  const l = o.limit;
  if (l.op === "equals") return "";
  if (l.op === "event") return Number.isFinite(o.peak) ? `${o.peak} phone${o.peak === 1 ? "" : "s"}` : "";
  return `${fmt(o.peak, Math.abs(o.peak) >= 100 ? 0 : 2)}${unitText(l.unit)}`;
}

// The alarm list at the cursor: severity, channel, limit, raised, cleared, worst value, acknowledgement.
export class AlarmPanel {
  // onChange: called when an acknowledgement's POST was answered (the panel is to be redrawn).
  constructor(token, onChange = () => {}) {
    this.token = token;
    this.onChange = onChange;
    this.key = "";
    this.sending = new Set();  // "key@raised_t" POSTed, waiting for the run's alarm_ack event
    this.errors = new Map();
    this.canAck = false;
    this.drawn = null;  // the Alarms the table shows (a new one for each run)
  }

  // staleAge (s): how old the newest row is when the feed is stale (the host silent or hung, a followed run
  // not growing), else 0 — the badge then says the alarm state is as of that row, never green: before, a
  // hung host's page said "alarms: none active" in green beside its "stale" feed badge.
  draw(alarms, t, canAck, staleAge = 0) {
    const rows = alarms ? alarms.at(t) : [];
    const key = `${alarms ? alarms.version : -1}/${rows.map((r) => `${r.active ? 1 : 0}${r.acked ? 1 : 0}`).join("")}/${canAck}/${this.sending.size}/${this.errors.size}`;
    const activeCount = rows.filter((r) => r.active).length;
    const unacked = rows.filter((r) => !r.acked).length;
    const worst = rows.filter((r) => r.active).reduce((w, r) => (SEVERITY_RANK[r.o.limit.severity] > SEVERITY_RANK[w] ? r.o.limit.severity : w), "");
    const badge = $("alarm-badge");
    const stale = staleAge > 0;
    const text = `${activeCount ? `${activeCount} active` : rows.length ? "none active" : "none"}${stale ? `, as of ${staleAge.toFixed(1)} s ago` : ""}`;
    if (badge.textContent !== `alarms: ${text}`) badge.textContent = `alarms: ${text}`;
    badge.className = `badge ${worst === "critical" ? "bad" : worst === "warning" ? "stale" : stale ? "" : "live"}`;
    const occurrences = alarms && alarms.occurrencesDropped ? `; ${alarms.occurrencesDropped} older cleared alarms dropped by this page (before t ${fmt(alarms.occurrencesFrom, 2)} s)` : "";
    const dropped = `${occurrences}${alarms && alarms.acksDropped ? `; ${alarms.acksDropped} acknowledgements naming no alarm dropped by this page` : ""}`;
    $("alarm-count").textContent = `(${activeCount} active, ${unacked} not acknowledged${dropped})`;
    // the same key of another run's alarms (a new run on the page: its own list, its version from 0 again)
    // is another table: the old run's rows were kept
    if (key === this.key && alarms === this.drawn) return;
    this.key = key;
    this.drawn = alarms;
    this.canAck = canAck;
    const body = document.querySelector("#alarms tbody");
    body.innerHTML = "";
    if (!rows.length) {
      body.innerHTML = `<tr><td colspan="7" class="muted">no alarm${alarms && alarms.limits.length ? "" : " (no limits: the run has no scenario)"}</td></tr>`;
      return;
    }
    for (const { o, active, acked } of rows) {
      const tr = document.createElement("tr");
      tr.dataset.key = o.key;
      tr.dataset.raised = String(o.raised_t);
      tr.className = `${o.limit.severity}${active ? " active" : " cleared"}`;
      const cells = [o.limit.severity, o.limit.label, limitText(o.limit), fmt(o.raised_t, 2),
        o.cleared_t !== null && !active ? fmt(o.cleared_t, 2) : "active", peakText(o)];
      for (const [k, text] of cells.entries()) {
        const td = document.createElement("td");
        td.textContent = text;
        td.className = ["sev", "channel", "limit", "raised", "cleared", "peak"][k];
        tr.appendChild(td);
      }
      tr.title = o.limit.why || "";
      const ackCell = document.createElement("td");
      ackCell.className = "ack";
      const id = `${o.key}@${o.raised_t}`;
      if (acked) {
        ackCell.textContent = `✓ ${fmt(o.ack.t, 1)} s`;
        ackCell.title = `acknowledged at ${shortText(o.ack.t)} s by ${shortText(o.ack.remote || o.ack.origin)}`;
      } else if (this.errors.has(id)) {
        ackCell.textContent = this.errors.get(id);
      } else if (canAck) {
        const button = document.createElement("button");
        button.textContent = this.sending.has(id) ? "sent…" : "Ack";
        button.title = "acknowledge this alarm (logged in the run's events)";
        button.disabled = this.sending.has(id);
        button.dataset.alarm = o.key;
        button.addEventListener("click", () => this.acknowledge(o, id));
        ackCell.appendChild(button);
      } else {
        ackCell.textContent = "—";
      }
      tr.appendChild(ackCell);
      body.appendChild(tr);
    }
  }

  async acknowledge(o, id) {
    if (!this.canAck) return;
    this.sending.add(id);
    this.key = "";
    this.onChange();
    try {
      const answer = await fetch("/api/ack", {
        method: "POST",
        headers: { "Content-Type": "application/json", "Authorization": `token ${this.token}` },
        body: JSON.stringify({ alarm: o.key, raised_t: o.raised_t }),
      });
      if (!answer.ok) {
        const reply = await answer.json().catch(() => ({}));
        this.errors.set(id, `refused: ${reply.error || answer.status}`);
        this.sending.delete(id);
      }
    } catch (err) {  // the host went away between the click and the answer
      this.errors.set(id, "not sent: the host does not answer");
      this.sending.delete(id);
    }
    this.key = "";
    this.onChange();
  }
}
