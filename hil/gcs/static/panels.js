// The status panels, the units table and the event log, drawn for the row at the cursor. A value that is
// old looks old: the cell gets the "stale" class (grey, hatched) and its age.

export const $ = (id) => document.getElementById(id);

// Three finite numbers (a command's target as roll/pitch/yaw or as a rotation vector), else null: an event is
// shown as events.jsonl has it, hand-edited or damaged ones too, and a malformed target is no target (never
// "NaN°", "undefined°", or a made-up one). hil/plots/markers.py keeps the same rule for the saved figures.
export function threeNumbers(v) {
  return Array.isArray(v) && v.length === 3 && v.every((x) => typeof x === "number" && Number.isFinite(x)) ? v : null;
}

export function fmt(v, digits = 2, unit = "") {
  return Number.isFinite(v) ? `${v.toFixed(digits)}${unit}` : "—";
}

function ageText(seconds) {
  return seconds >= 10 ? `${seconds.toFixed(0)} s old` : seconds >= 1 ? `${seconds.toFixed(1)} s old` : `${(seconds * 1e3).toFixed(0)} ms old`;
}

// Set a cell's text; stale (an age in s, a few words saying why, or false) greys it and says so.
export function setCell(el, text, staleAge = false) {
  if (!el) return;
  if (el.textContent !== text) el.textContent = text;
  const stale = staleAge !== false && staleAge !== null;
  el.classList.toggle("stale", stale);
  if (stale) el.dataset.age = Number.isFinite(staleAge) ? ageText(staleAge) : String(staleAge);
  else delete el.dataset.age;
}

function enumName(info, kind, v) {
  if (!Number.isFinite(v)) return "—";
  const names = (info.enums || {})[kind] || {};
  return names[String(Math.round(v))] || String(v);
}

function faultNames(info, v) {
  if (!Number.isFinite(v)) return "—";
  if (!v) return "none";
  const names = (info.enums || {}).faults || {};
  return Object.entries(names).filter(([bit]) => v & Number(bit)).map(([, n]) => n).join(", ") || `0x${v.toString(16)}`;
}

const PILL = { ARMED: "ok", DISARMED: "", BOOT: "warn", FAILSAFE: "bad", OK: "ok", LINK_LOST: "bad",
  NORMAL: "ok", WARN: "warn", LIMIT: "warn", SHED: "bad", BROWN_OUT: "bad" };

function setPill(el, name, staleAge) {
  setCell(el, name, staleAge);
  el.className = `pill ${(Object.hasOwn(PILL, name) && PILL[name]) || ""}${el.classList.contains("stale") ? " stale" : ""}`;
}

// What a value after the run's end is marked with (the run has ended, the cursor at its end): the last row's,
// as of the run's end, never live.
export const AT_RUN_END = "at the run's end";

// The board's state the run's end said, the cursor at the end of a run that has ended: its final Disarm's
// (summary.json's final_disarm: the board's state as last known once the run's way out ran), else the way
// out's own record at or after the last row (`disarmed`; `disarm_failed`: the row's state, not confirmed);
// else the last row's. The last row comes before the way out's Disarm: it said ARMED for a run that then
// disarmed its board, and the page showed the board ARMED after the run's end.
function boardStateAtEnd(ctx, rowState) {
  const fd = (ctx.summary || {}).final_disarm;
  if (fd && typeof fd.state === "string" && fd.state) return fd.ok === false ? `${fd.state} (final Disarm failed)` : fd.state;
  const { store, i } = ctx;
  const tRow = store.value("t", i);
  for (let k = store.events.length - 1; k >= 0; k--) {
    const e = store.events[k];
    if (!(e.t >= tRow)) break;
    if (e.kind === "disarmed") return "DISARMED";
    if (e.kind === "disarm_failed") return `${rowState} (final Disarm failed)`;
  }
  if (fd && fd.ok === false) return `${rowState} (final Disarm failed)`;
  return rowState;
}

// ctx: {info, store, i (row index), t (cursor time), feedAge (s: the feed's age, at a live or followed run's
// newest row), rowGap (s before row i), ended (the run has ended), atEnd (the cursor at the newest row),
// summary (the run's, once it has ended)}
export function drawPanels(ctx) {
  const { info, store, i } = ctx;
  const v = (name) => store.value(name, i);
  const staleAfter = info.stale_after_s || 0.25;
  // Board telemetry is stale when the host's copy is old (live), when rows stopped coming (a gap before
  // this row, or the feed itself silent); after the run's end, at its end, it is as of the run's end.
  const telAge = Number.isFinite(v("tel_age_ms")) ? v("tel_age_ms") / 1e3 : 0;
  const boardAge = Math.max(telAge, ctx.rowGap || 0, ctx.feedAge || 0);
  const atRunEnd = Boolean(ctx.ended && ctx.atEnd);
  const boardStale = atRunEnd ? AT_RUN_END : boardAge > staleAfter ? boardAge : false;

  setCell($("time"), fmt(ctx.t, 2));
  setCell($("phase"), enumName(info, "phase", v("phase")), boardStale);  // names from info (Python's enum)
  // The host's view of the board (telemetry.csv's board_link): a row without a live board has no board
  // value at all; say why rather than show "—".
  const link = v("board_link");
  const blind = Number.isFinite(link) && link !== 0;
  const why = enumName(info, "board_link", link) === "LOST" ? "link lost" : "no telemetry";
  const rowState = blind ? `UNKNOWN (${why})` : enumName(info, "board_state", v("board_state"));
  const state = atRunEnd ? boardStateAtEnd(ctx, rowState) : rowState;
  setPill($("board-state"), state, boardStale);
  if (blind || state.endsWith("(final Disarm failed)")) $("board-state").classList.add("bad");
  setPill($("watchdog"), enumName(info, "watchdog", v("watchdog")), boardStale);
  setPill($("power-state"), enumName(info, "power_state", v("power_state")), boardStale);

  setCell($("board-mode"), `${state} / ${enumName(info, "board_mode", v("board_mode"))}`, boardStale);
  setCell($("faults"), faultNames(info, v("faults")), boardStale);
  const linkAge = v("link_age_ms");
  setCell($("link-age"), fmt(linkAge, 0, " ms ago"), !atRunEnd && linkAge > staleAfter * 1e3 ? linkAge / 1e3 : boardStale);
  // The host's age of the board's telemetry, as of the row shown; when the feed itself is silent (the host
  // died) the row is that old too, and the cell says so like every other.
  setCell($("tel-age"), store.has("tel_age_ms") ? fmt(v("tel_age_ms"), 0, " ms ago") : "not recorded", boardStale);

  setCell($("battery"), `${fmt(v("battery_v"), 2, " V")}  ${fmt(v("battery_a"), 2, " A")}  ${fmt(v("battery_soc"), 0, " %")}`, boardStale);
  setCell($("ubec"), `${fmt(v("ubec_v"), 2, " V")}  ${fmt(v("ubec_a"), 2, " A")}`, boardStale);
  setCell($("power"), enumName(info, "power_state", v("power_state")), boardStale);

  drawUnits(ctx, boardStale);
  drawPhone(ctx);
  drawSenders(ctx);
  drawLink(ctx);
  markAlarms(ctx);
}

// The cell showing each channel, coloured while one of its alarms is active at the cursor.
function alarmCells(info) {
  const cells = { point_err_deg: "point-err", battery_v: "battery", ubec_v: "ubec", link_age_ms: "link-age",
    tel_age_ms: "tel-age", board_state: "board-mode", phone_other_phones: "phone-others" };
  for (let k = 0; k < (info.n_units || 0); k++) {
    cells[`gimbal_rate_${k}`] = `u${k}-rate`;
    cells[`rotor_speed_${k}`] = `u${k}-rotor`;
  }
  return cells;
}

function markAlarms(ctx) {
  const active = ctx.alarmColumns || {};
  for (const [column, id] of Object.entries(alarmCells(ctx.info))) {
    const el = $(id);
    if (!el) continue;
    const severity = active[column] || "";
    if ((el.dataset.alarm || "") === severity) continue;
    el.classList.toggle("alarm-warning", severity === "warning");
    el.classList.toggle("alarm-critical", severity === "critical");
    if (severity) el.dataset.alarm = severity; else delete el.dataset.alarm;
  }
}

function drawUnits(ctx, boardStale) {
  const { info, store, i } = ctx;
  const body = document.querySelector("#units tbody");
  const n = info.n_units || 0;
  if (body.children.length !== n) {
    body.innerHTML = "";
    for (let k = 0; k < n; k++) {
      const tr = document.createElement("tr");
      tr.innerHTML = `<td>${k + 1}</td><td id="u${k}-angle"></td><td id="u${k}-rate"></td><td id="u${k}-rotor"></td><td id="u${k}-pulse"></td>`;
      body.appendChild(tr);
    }
  }
  const maxRate = (info.limits || {}).max_gimbal_rate;
  for (let k = 0; k < n; k++) {
    const rate = store.value(`gimbal_rate_${k}`, i);
    setCell($(`u${k}-angle`), fmt(store.value(`gimbal_angle_${k}`, i) * 180 / Math.PI, 1), boardStale);
    const rateCell = $(`u${k}-rate`);
    setCell(rateCell, fmt(rate, 3), boardStale);
    rateCell.style.color = maxRate && Math.abs(rate) > 0.9 * maxRate ? "var(--bad)" : "";
    setCell($(`u${k}-rotor`), fmt(store.value(`rotor_speed_${k}`, i), 0), boardStale);
    setCell($(`u${k}-pulse`), `${fmt(store.value(`pulse_gimbal_${k}`, i), 0)} / ${fmt(store.value(`pulse_rotor_${k}`, i), 0)}`, boardStale);
  }
}

function drawPhone(ctx) {
  const { info, store, i } = ctx;
  const body = document.querySelector("#phone tbody");
  const labels = info.phone || [];
  if (body.children.length !== labels.length) {
    body.innerHTML = "";
    for (const k of labels) {
      const tr = document.createElement("tr");
      tr.innerHTML = `<td>${k}</td><td id="phone-rate-${k}"></td><td id="phone-age-${k}"></td>`;
      body.appendChild(tr);
    }
  }
  const staleAfter = info.stale_after_s || 0.25;
  for (const k of labels) {
    if (!store.has(`phone_age_ms_${k}`)) {
      setCell($(`phone-rate-${k}`), "not recorded");
      setCell($(`phone-age-${k}`), "—");
      continue;
    }
    const age = store.value(`phone_age_ms_${k}`, i) / 1e3 + (ctx.feedAge || 0);
    const stale = !Number.isFinite(age) ? "no sample yet" : ctx.ended && ctx.atEnd ? AT_RUN_END : age > staleAfter ? age : false;
    setCell($(`phone-rate-${k}`), fmt(store.value(`phone_rate_${k}`, i), 1), stale);
    setCell($(`phone-age-${k}`), Number.isFinite(age) ? `${(age * 1e3).toFixed(0)} ms ago` : "none yet", stale);
  }
}

// The one-phone rule's records (hil/link/sources/senders.py, docs/formats.md "One phone per receiver").
const SENDER_KINDS = new Set(["phone_following", "phone_other", "phone_switch", "phone_others_quiet"]);

// The phone followed and the other phones dropped, at the cursor: the row's live counts (a live run), or
// the counts of the newest record of the rule at or before the cursor (a replay: "as of" its time), or the
// run's final counts once it has ended and the cursor is at its end ("at the end of the run") — a count is
// never shown as live once the stream has ended. Without a receiver (a world stepped in-process, a
// recording) no other phone can stream to the run: it says so.
function drawSenders(ctx) {
  const { store, i, t } = ctx;
  const cells = { following: $("phone-following"), others: $("phone-others"), messages: $("phone-other-messages"), switches: $("phone-switches") };
  if (!cells.following) return;
  let listening = null, rule = null, followed = null;
  for (const e of store.events) {
    if (e.t > t) break;
    if (e.kind === "phone_listening") listening = e;
    else if (SENDER_KINDS.has(e.kind)) {
      rule = e;
      if (e.kind === "phone_following" || e.kind === "phone_switch") followed = e;
    }
  }
  const final = (ctx.summary || {}).phone;
  // stale: the counts' (and, but for a replay's records, the phone followed's: a record says it exactly)
  const show = (following, counts, stale, followingStale = stale) => {
    setCell(cells.following, following, followingStale);
    setCell(cells.others, counts ? String(counts[0]) : "—", stale);
    setCell(cells.messages, counts ? String(counts[1]) : "—", stale);
    setCell(cells.switches, counts ? String(counts[2]) : "—", stale);
  };
  if (ctx.ended && ctx.atEnd && final && "other_phones" in final) {
    show(final.following || "none", [final.other_phones, final.other_phone_messages, final.phone_switches], "at the end of the run");
    return;
  }
  const live = ["phone_other_phones", "phone_other_messages", "phone_switches"].map((c) => store.value(c, i));
  const following = followed ? followed.sender : listening ? "none heard yet" : "";
  if (live.every(Number.isFinite)) {
    const age = ctx.feedAge || 0;
    show(following || "none heard yet", live, age > (ctx.info.stale_after_s || 0.25) ? age : false);
  } else if (rule) {
    const counts = [rule.other_phones, rule.other_phone_messages, rule.phone_switches];
    show(following, counts, `as of ${fmt(rule.t, 1)} s`, false);
  } else if (listening) {
    show(following, [0, 0, 0], false);  // the first other phone's message always makes a record
  } else {
    show("no receiver: the run's phone is not on a port", null, false);
  }
}

const LINK_ROWS = [
  ["frames_in", "frames received"], ["bad_frames_total", "bad frames"], ["resyncs", "resyncs"],
  ["seq_gaps", "sequence gaps"], ["counters.frames_out", "frames sent"], ["retries", "command retries"],
  ["acked", "acked / nacked / failed"], ["rtt.p99_ms", "command RTT p50 / p99"],
  ["counters.link_losses", "link losses / reconnects"], ["board_rx_bad", "board: frames / bad"],
  ["bytes_in", "bytes in / out"],
];

function drawLink(ctx) {
  const { store, t } = ctx;
  const table = $("link");
  // A replay has the run's final figures only (summary.json): shown, marked as from the end of the run.
  const atEnd = !store.linkAt(t) && store.link.length ? store.link[store.link.length - 1] : null;
  const s = store.linkAt(t) || atEnd;
  if (!s) { table.innerHTML = "<tr><td class='muted'>no link statistics yet</td></tr>"; table.dataset.built = ""; return; }
  if (!table.dataset.built) {
    table.innerHTML = LINK_ROWS.map(([k, label]) => `<tr><th>${label}</th><td id="link-${k.replace(/\./g, "-")}"></td></tr>`).join("")
      + `<tr><th>bad frames by reason</th><td id="link-reasons"></td></tr>`;
    table.dataset.built = "1";
  }
  const age = Number.isFinite(s.t) && Number.isFinite(t) ? Math.max(t - s.t, 0) + (ctx.feedAge || 0) : 0;
  const stale = atEnd ? "at the end of the run" : age > 1.0 ? age : false;
  const n = (k) => (s[k] === null || s[k] === undefined ? "—" : String(s[k]));
  const vals = {
    "frames_in": n("frames_in"), "resyncs": n("resyncs"),
    // a live snapshot has the total; a run's summary.json only the counts by reason
    "bad_frames_total": String(s.bad_frames_total ?? Object.entries(s).filter(([k]) => k.startsWith("bad_frames."))
      .reduce((sum, [, x]) => sum + (Number(x) || 0), 0)),
    "seq_gaps": n("seq_gaps"), "counters.frames_out": n("counters.frames_out"), "retries": n("retries"),
    "acked": `${n("acked")} / ${n("nacked")} / ${n("failed")}`,
    "rtt.p99_ms": `${fmt(s["rtt.p50_ms"], 1)} / ${fmt(s["rtt.p99_ms"], 1)} ms`,
    "counters.link_losses": `${n("counters.link_losses")} / ${n("counters.reconnects")}`,
    "board_rx_bad": `${n("board_rx_frames")} / ${n("board_rx_bad")}`,
    "bytes_in": `${n("bytes_in")} / ${n("bytes_out")}`,
  };
  for (const [k, text] of Object.entries(vals)) setCell($(`link-${k.replace(/\./g, "-")}`), text, stale);
  const reasons = Object.entries(s).filter(([k, x]) => k.startsWith("bad_frames.") && x).map(([k, x]) => `${k.slice(11)} ${x}`);
  setCell($("link-reasons"), reasons.join(", ") || "none", stale);
}

const EVENT_CLASS = (e) => {
  if (e.kind === "command") return "cmd";
  if (e.kind === "board_reset" || e.kind === "link_lost" || (e.kind === "board_state" && e.new === "FAILSAFE")) return "bad";
  if (e.kind === "silence" || e.kind === "rearm_failed" || (e.kind === "board_log" && e.severity !== "INFO")) return "warn";
  if (e.kind === "phone_other" || e.kind === "phone_switch") return "warn";
  return "";
};

// A record's field as text: numbers to 4 significant digits (an event's rotation vectors and times are for
// reading, not for copying), lists and objects by their content — String() of an object, from a run
// directory's events (any JSON), was "[object Object]" in the markers, the command history and the uplink log.
export function shortText(x) {
  if (typeof x === "number") return Number.isInteger(x) ? String(x) : String(Number(x.toPrecision(4)));
  if (Array.isArray(x)) return `[${x.map(shortText).join(", ")}]`;
  if (x !== null && typeof x === "object") return Object.entries(x).map(([k, v]) => `${k} ${shortText(v)}`).join(", ");
  return String(x);
}

// An event's fields but its time and kind, as "name value" pairs (a cell that wraps, never a line that
// scrolls sideways).
function details(e) {
  return Object.entries(e).filter(([k, x]) => k !== "t" && k !== "kind" && x !== null && x !== "")
    .map(([k, x]) => `${k.replace(/_/g, " ")}: ${shortText(x)}`).join(" · ");
}

// The newest events at or before the cursor, as a table (redrawn only when they change: other events — a
// new store's, another run's — or another count of them). Keyed by the counts alone, a new run on the page
// (hil/gcs/static/app.js, onInfo) with as many events as the old one kept showing the old run's.
let eventsDrawn = null;  // the events array the table shows (the store's: a new one for each run)
export function drawEvents(store, t, limit = 200) {
  const body = document.querySelector("#events tbody");
  let end = store.events.length;
  while (end > 0 && store.events[end - 1].t > t) end--;
  const key = `${end}/${store.events.length}`;
  if (body.dataset.key === key && eventsDrawn === store.events) return;
  body.dataset.key = key;
  eventsDrawn = store.events;
  const shown = store.events.slice(Math.max(0, end - limit), end).reverse();
  body.innerHTML = "";
  for (const e of shown) {
    const tr = document.createElement("tr");
    tr.className = EVENT_CLASS(e);
    tr.dataset.kind = e.kind;
    for (const [cls, text] of [["t", Number.isFinite(e.t) ? e.t.toFixed(2) : ""], ["kind", e.kind], ["details", details(e)]]) {
      const td = document.createElement("td");
      td.className = cls;
      td.textContent = text;
      tr.appendChild(td);
    }
    body.appendChild(tr);
  }
  const dropped = store.eventsDropped ? `; ${store.eventsDropped} older dropped by this page` : "";
  $("event-count").textContent = `(${end} of ${store.events.length}${dropped})`;
}
