// The ground station page: the downlink (Server-Sent Events) into the store, a timeline cursor (following
// the newest data, or scrubbed / played back), and a redraw of plots, 3D view and panels in the next
// animation frame whenever something changed — and only then: an idle page draws nothing (its drawing is
// what it costs the machine a run shares with it). Counters for tests and benchmarks: window.gcs.stats.

import { Store } from "./store.js";
import { Plots } from "./plots.js";
import { View3D, rotvecToMatrix, eulerZYX } from "./view3d.js";
import { $, fmt, setCell, drawPanels, drawEvents, shortText, threeNumbers, AT_RUN_END } from "./panels.js";
import { Uplink } from "./uplink.js";
import { Alarms, AlarmPanel } from "./alarms.js";
import { drawHistory, exportHistory, commandEvents } from "./commands.js";

const CLOCK_MS = 250;       // the feed's age is checked this often (a silent feed turns stale)
const RETRY_MS = [1000, 2000, 4000, 8000, 10000];  // a stream the server refused is opened again after these
const FEED_STALE_S = 1.0;  // nothing of the run's progress for this long: the live feed is stale
// What counts as the run's progress, and so as its host being alive: what the run itself makes — its rows,
// events and link figures (and its description) — and a status whose state changed or whose `ticks` (the
// run's control ticks, hil/gcs/live.py) moved. Not any message: a status also goes out when a counter of
// the server's changes (a refused request), which it does while the run's control thread is hung. And
// never the history: every (re)connection begins with `info` and the run's history again, which ends with
// a `caught_up` message saying how long ago the run last made progress (hil/gcs/hub.py); until then
// nothing counts (a page that reconnected to a hung run was "receiving" its history for 1 s, buttons on).
const PROGRESS = new Set(["info", "rows", "events", "link"]);
const NOT_PROGRESS = "stopped";  // a status state that is no progress when it comes (isProgress)

// A downlink message is data, never behaviour. A run directory's events.jsonl and summary.json may hold any
// JSON, and an object whose own "toString" or "valueOf" is a value ({"command": {"toString": 1}}) cannot be
// made text or a number: String(), a template, a comparison (`e.t > t`), a dataset assignment throw a
// TypeError — one such record in a replay threw on every redraw, the stats and everything after it never
// drawn again. Such keys are kept under another name (the events table still shows them); the rows
// (NUMBERS_ONLY: numbers and nulls, hil/gcs/wire.py's encode_rows) are parsed without the reviver's cost.
const SHADOWING_KEYS = new Set(["toString", "valueOf"]);
const NUMBERS_ONLY = new Set(["rows", "overlay_rows"]);
function asData(key, value) {
  if (value === null || typeof value !== "object" || Array.isArray(value)) return value;
  if (!Object.keys(value).some((k) => SHADOWING_KEYS.has(k))) return value;
  return Object.fromEntries(Object.entries(value).map(([k, v]) => [SHADOWING_KEYS.has(k) ? `${k} (as sent)` : k, v]));
}

const token = new URLSearchParams(location.search).get("token") || "";
const view = new View3D($("view3d"));
const uplink = new Uplink(token);
uplink.enable(false, "Connecting: no commands yet.");
const alarmPanel = new AlarmPanel(token, () => invalidate());

const state = {
  info: null, store: null, plots: null, alarms: null, overlays: [], status: {}, follow: true, cursor: NaN, playing: false,
  dirty: false, lastMessage: performance.now(), lastProgress: performance.now(), ended: false, connected: false,
  history: false,  // between an `info` and its `caught_up`: the history (re)sent, not the run's progress
  refused: "",  // why the server refused the stream, while it is refused (refusedStream)
  skips: [],  // where this page fell behind and the server trimmed what it had not read: [{chunks, after, until}]
  // The feed's lag (hostLag): this page's clock (performance.now, s) less the host's monotonic clock, set by
  // each `caught_up` (written as the stream sends it) and tightened by any status that comes sooner (an
  // offset seen is never below the true one: a message is never early), and the host's clock at the newest
  // live status (hil/gcs/live.py, poll); null: unknown. Monotonic both: a wall clock's step is no lag.
  hostOffset: null, hostTime: null,
};
const stats = { messages: 0, rows: 0, bytes: 0, renders: 0, dataRenders: 0, updateHz: 0, renderTimes: [], histories: 0 };
window.gcs = { state, stats };

// ---------------------------------------------------------------- the downlink
function connect() {
  if (!token) {
    $("note").textContent = "no token in the URL: open the address hil printed (…/?token=…)";
    return;
  }
  const es = new EventSource(`/api/stream?token=${encodeURIComponent(token)}`);
  const on = (name, fn) => es.addEventListener(name, (m) => {
    stats.messages += 1; stats.bytes += m.data.length;
    const data = NUMBERS_ONLY.has(name) ? JSON.parse(m.data) : JSON.parse(m.data, asData);
    state.lastMessage = performance.now();
    if (!state.history && isProgress(name, data, state.status)) state.lastProgress = state.lastMessage;
    fn(data);
  });
  es.onopen = () => { state.connected = true; state.refused = ""; refusals = 0; };
  es.onerror = () => {
    state.connected = false;
    if (state.ended) es.close();
    else if (es.readyState === EventSource.CLOSED) refusedStream();
  };
  on("info", onInfo);
  on("rows", (d) => {
    if (!state.store) return;
    const skip = state.skips[state.skips.length - 1];
    if (skip && skip.until === null && d.rows.length) { skip.until = d.rows[0][0]; showStatus(); }
    state.alarms.feed(d.rows); state.store.pushRows(d.rows); stats.rows += d.rows.length; invalidate();
  });
  // This page fell behind and the server trimmed chunks it had not read (hil/gcs/hub.py, skipped): their rows
  // are missing between the last row held and the next one to come, said in the note rather than drawn across.
  // `history`: the run's first chunks, trimmed before this page connected — its start is missing.
  on("skipped", (d) => {
    const store = state.store;
    const after = store && store.n ? store.data[0][store.n - 1] : null;
    state.skips.push({ chunks: d.chunks, after, until: null, history: d.history === true });
    showStatus();
  });
  on("events", (list) => {
    if (!state.store) return;
    const dropped = state.store.eventsDropped;
    state.store.pushEvents(list); state.alarms.onEvents(list); list.forEach((e) => uplink.onEvent(e)); invalidate();
    if (state.store.eventsDropped !== dropped) showStatus();  // the note says where the events now start
  });
  // runs compared (hil/gcs/compare.py): another run's description, then its rows
  on("overlay", (o) => {
    if (!state.store) return;
    state.overlays[o.run] = { name: o.name, store: new Store(o.columns), note: o.note };
    buildPlots();
    invalidate();
  });
  on("overlay_rows", (d) => { const o = state.overlays[d.run]; if (o) { o.store.pushRows(d.rows); invalidate(); } });
  on("link", (list) => { if (state.store) { state.store.pushLink(list); invalidate(); } });
  // the history has been sent: the run's last progress was progress_age_s ago (null: none yet)
  on("caught_up", (d) => {
    state.history = false;
    stats.histories += 1;
    if (typeof d.progress_age_s === "number") state.lastProgress = state.lastMessage - 1e3 * d.progress_age_s;
    if (typeof d.host_time === "number") state.hostOffset = performance.now() / 1e3 - d.host_time;
    invalidate();
  });
  on("status", (s) => {
    if (typeof s.host_time === "number") {
      state.hostTime = s.host_time;
      const offset = performance.now() / 1e3 - s.host_time;
      if (!state.history && state.hostOffset !== null && offset < state.hostOffset) state.hostOffset = offset;
    }
    state.status = { ...state.status, ...s };
    invalidate();
    showStatus();
    showFeed();
  });
  es.addEventListener("bye", () => { state.ended = true; es.close(); showStatus(); showFeed(); });
}

// EventSource reconnects by itself after a network error, but an answer other than 200 fails it for good:
// the server's 503 when every stream slot is taken (other tabs, a reconnect storm, streams it has not yet
// seen closed), a 401 / 403 for the token or origin. A page that did not look said "reconnecting" for ever
// and never came back. Now it asks why (/api/info with the token): a refused token or origin is said and
// not retried (each attempt is a refusal logged in the run's events); anything else is tried again,
// RETRY_MS apart, the badge saying so.
let refusals = 0;
async function refusedStream() {
  let status = 0;
  try {
    status = (await fetch(`/api/info?token=${encodeURIComponent(token)}`, { cache: "no-store" })).status;
  } catch (err) {
    status = 0;  // the host does not answer
  }
  if (status === 401 || status === 403) {
    state.refused = status === 401 ? "refused: wrong or missing token (open the address hil printed)"
      : "refused: this page's origin or host is not the server's";
  } else {
    const wait = RETRY_MS[Math.min(refusals, RETRY_MS.length - 1)];
    refusals += 1;
    state.refused = `stream refused by the server (${status || "no answer"}): trying again in ${wait / 1e3} s`;
    setTimeout(connect, wait);
  }
  showFeed();
}

// Whether a downlink message is the run's own progress (PROGRESS, above); `status` is the one before it.
function isProgress(name, data, status) {
  if (PROGRESS.has(name)) return true;
  if (name !== "status") return false;
  // "stopped" (a followed run directory's writer gone) is the reader's verdict that nothing more comes, not
  // the run's progress: counted as progress, it made the newest row's age start again from 0 at the verdict
  const changed = data.state !== undefined && data.state !== status.state && data.state !== NOT_PROGRESS;
  const ticked = data.ticks !== undefined && data.ticks !== status.ticks;
  return changed || ticked;
}

function buildPlots() {
  if (state.plots) state.plots.destroy();
  state.plots = new Plots($("plots"), state.info, state.store, () => { invalidate(); }, state.overlays.filter(Boolean));
}

// Light or dark follows the system (CSS prefers-color-scheme); the plots' canvas colours are taken from the
// page's style when they are built, so a change of scheme rebuilds them.
matchMedia("(prefers-color-scheme: dark)").addEventListener("change", () => { if (state.store) { buildPlots(); invalidate(); } });

function onInfo(info) {
  // The same run described again: the stream reconnected and its history follows. The operator's cursor
  // (scrubbed back, playing) is kept; another run starts following its newest row.
  const same = state.info && state.info.run === info.run && state.info.mode === info.mode
    && JSON.stringify(state.info.columns) === JSON.stringify(info.columns);
  state.info = info;
  state.history = true;
  state.store = new Store(info.columns);
  state.alarms = new Alarms(info);
  state.overlays = [];
  state.skips = [];  // a new store, the history again from the start: the holes of the old one are gone
  state.hostTime = null;  // a new run (a host restarted): the old run's clock says nothing of this one's feed
  buildPlots();
  // Another run (a station at the same address and token after the old one died without a `bye`, a live
  // station's next run): nothing of the old run's is this one's. Each status is merged into the one before
  // (a status says only what changed), so the old run's `exit` and `summary` stayed — the new run, still
  // being written, read "lost" and showed the old board's state at its end — and the uplink's lines of the
  // old run's commands took the new run's command of the same id. The same run described again (a
  // reconnection) keeps its status: its history may no longer hold the status that said its state.
  if (!same) {
    state.follow = true; state.playing = false;
    state.status = {};
    uplink.newRun();
  }
  $("run-name").textContent = info.compare ? `compared: ${info.compare.join(" · ")} (the timeline is ${info.run}'s)`
    : info.run + (info.scenario ? ` · ${info.scenario}` : "");
  $("note").textContent = info.note || "";
  $("link").dataset.built = "";
  document.title = `GCS · ${info.run}`;
  invalidate();
}

function showStatus() {
  const s = state.status;
  const parts = [];
  if (runFailedToStart()) parts.push(`the run failed to start: ${s.exit ? shortText(s.exit) : "no word why"}`);
  else if (s.exit) parts.push(`exit: ${shortText(s.exit)}`);  // a summary's: any JSON
  // what the live feed dropped (the pump starved: hil/gcs/live.py), each kind said — a dropped event (a
  // failsafe, a command's status, the record that clears an alarm) is missing from the events, the command
  // history and the alarms; before, only dropped rows were said, and dropped events were not told at all
  if (s.feed_dropped_rows) parts.push(`${s.feed_dropped_rows} rows dropped by the feed`);
  if (s.feed_dropped_events) parts.push(`${s.feed_dropped_events} events dropped by the feed (missing here, kept in events.jsonl)`);
  if (s.feed_dropped_link) parts.push(`${s.feed_dropped_link} link figures dropped by the feed`);
  if (s.bad_rows) parts.push(`${s.bad_rows} unreadable rows`);
  if (s.uplink_rejected) parts.push(`${s.uplink_rejected} requests refused`);
  if (s.error) parts.push(`error: ${s.error}`);
  if (state.skips.length) parts.push(skipsText(state.skips));
  // the oldest events dropped by this page past its bound (store.js MAX_EVENTS): said, never silent
  const store = state.store;
  if (store && store.eventsDropped) {
    const from = Number.isFinite(store.eventsFrom) ? ` before t ${store.eventsFrom.toFixed(2)} s` : "";
    parts.push(`${store.eventsDropped} older events dropped by this page${from} (events, command history and markers start there; all in events.jsonl)`);
  }
  if (s.state === "stopped" && s.stopped) parts.push(s.stopped);
  // runs compared: an overlay that cannot be drawn, or stopped being followed, says why (hil/gcs/compare.py)
  for (const [name, o] of Object.entries(s.overlays || {})) {
    if (o && o.error) parts.push(`${name}: ${o.error}`);
    else if (o && o.state === "stopped" && o.stopped) parts.push(`${name}: ${o.stopped}`);
  }
  $("note").textContent = [state.info && state.info.note, ...parts].filter(Boolean).join(" · ");
}

// What the note says of the chunks this page never got (state.skips): how many, and where their rows are
// missing — the run's start (the server's history no longer held it when this page connected), and where
// this page fell behind.
function skipsText(skips) {
  const at = (t) => (typeof t === "number" ? `${t.toFixed(2)} s` : "?");
  const parts = [];
  const start = skips.filter((k) => k.history);
  const behind = skips.filter((k) => !k.history);
  if (start.length) {
    const chunks = start.reduce((n, k) => n + k.chunks, 0);
    const until = start[start.length - 1].until;
    parts.push(`the run's start is missing: ${chunks} downlink chunks were gone from the server's history when this page connected (rows before t ${until === null ? "…" : at(until)})`);
  }
  if (behind.length) {
    const chunks = behind.reduce((n, k) => n + k.chunks, 0);
    const where = behind.map((k) => `t ${at(k.after)} – ${k.until === null ? "…" : at(k.until)}`).join(", ");
    parts.push(`fell behind: ${chunks} downlink chunks skipped, rows missing at ${where}`);
  }
  return parts.join(" · ");
}

// ---------------------------------------------------------------- the timeline
const timeline = $("timeline");
timeline.addEventListener("input", () => { state.follow = false; state.playing = false; state.cursor = Number(timeline.value); invalidate(); });
$("follow").addEventListener("click", () => { state.follow = true; state.playing = false; invalidate(); });
$("window").addEventListener("change", () => { invalidate(); });
$("export-history").addEventListener("click", () => {
  if (state.store) exportHistory(state.store.events, state.store.n ? state.cursor : Infinity, state.info.run);
});
function togglePlay() {
  const store = state.store;
  if (!store || !store.n) return;
  state.playing = !state.playing;
  if (state.playing) {
    state.follow = false;
    if (!(state.cursor < store.tLast)) state.cursor = store.tFirst;
    playClock = performance.now();
  }
  invalidate();
}
$("play").addEventListener("click", togglePlay);

// The cursor moved by the keyboard: by rows (a frame: the next or previous telemetry row) or by seconds;
// it stops following and playing, and stays within the run.
function step(rows, seconds) {
  const store = state.store;
  if (!store || !store.n) return;
  state.follow = false;
  state.playing = false;
  const t = store.col("t");
  const now = Number.isFinite(state.cursor) ? state.cursor : store.tLast;
  if (rows) {
    let i = store.indexAt(now);
    if (rows < 0 && i >= 0 && t[i] < now) i += 1;  // between two rows: the previous one is the row at i
    i = Math.min(Math.max(i + rows, 0), store.n - 1);
    state.cursor = t[i];
  } else {
    state.cursor = Math.min(Math.max(now + seconds, store.tFirst), store.tLast);
  }
  invalidate();
}

// Keys (docs/gcs.md): Space play/pause, ←/→ a frame, Shift+←/→ a second, f follow. Not while typing in a
// field; Space never presses a focused button (an operator's Space is for the timeline, not a command).
const KEY_ACTIONS = {
  " ": () => togglePlay(),
  "ArrowLeft": (ev) => (ev.shiftKey ? step(0, -1) : step(-1, 0)),
  "ArrowRight": (ev) => (ev.shiftKey ? step(0, 1) : step(1, 0)),
  "f": () => { state.follow = true; state.playing = false; invalidate(); },
};
document.addEventListener("keydown", (ev) => {
  if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const el = ev.target;
  const typing = (el.tagName === "INPUT" && el.type !== "range") || el.tagName === "SELECT" || el.tagName === "TEXTAREA";
  const key = ev.key === "F" ? "f" : ev.key;
  if (typing || !(key in KEY_ACTIONS)) return;
  ev.preventDefault();
  KEY_ACTIONS[key](ev);
});

// The feed's state, from the run's progress (isProgress), not from any message: a hung run whose server
// still answers (statuses counting refused requests) is "stale: host not ticking", its values stale.
function feedState() {
  const now = performance.now();
  const age = (now - state.lastProgress) / 1e3;  // since the run last made progress
  const heard = (now - state.lastMessage) / 1e3;  // since the server last said anything
  if (!state.info) return noRunFeed(heard);
  const live = state.info.mode === "live";
  const following = state.status.state === "following";
  if (state.ended || ["ended", "finished", "read"].includes(state.status.state)) return endedFeed();
  // a followed run directory whose writer is gone without a summary (killed, crashed: hil/gcs/rundir.py)
  if (state.status.state === "stopped") return { text: "stopped being written", cls: "stale", age };
  if ((live || following) && state.history) {
    // the history (re)sent: whether the run is alive is not known until it has all come
    return { text: `loading the history: nothing new for ${age.toFixed(1)} s`, cls: "stale", age };
  }
  if ((live || following) && age > FEED_STALE_S) {
    const what = heard > FEED_STALE_S ? "nothing" : live ? "host not ticking" : "run not growing";
    const refused = state.refused ? ` (${state.refused})` : "";
    return { text: `stale: ${what} for ${age.toFixed(1)} s${refused}`, cls: "stale", age };
  }
  // Every message comes, but late (a starved pump, a page that reads behind): the run's progress arrives
  // steadily, so only the host's clock tells it — its values are as old as the lag, and said so.
  const lag = live ? hostLag() : null;
  if (lag !== null && lag > FEED_STALE_S) {
    return { text: `stale: lagging ${lag.toFixed(1)} s behind the host`, cls: "stale", age: Math.max(age, lag) };
  }
  if (!state.connected) return { text: state.refused || `reconnecting: nothing for ${heard.toFixed(1)} s`, cls: "bad", age };
  return { text: live ? "receiving" : following ? "following" : "loaded", cls: "live", age: 0 };
}

// How far (s) the feed lags behind the host: the host's clock now, as this page reckons it from the
// offset its stream's `caught_up` set, less the host's clock at the newest status received; null when not
// known (a replay, a followed directory, a live run's history still loading, an older server).
function hostLag() {
  if (state.hostOffset === null || state.hostTime === null || state.history) return null;
  return Math.max(performance.now() / 1e3 - state.hostOffset - state.hostTime, 0);
}

// The feed of a run that has ended (a live run's end, a replay's summary, a directory read once): "ended" or
// "finished", and — when the summary says the run did not complete (lost, aborted, interrupted, disarmed by
// the operator, an error, incomplete) — how, in red ("failed": the badge's bad colour). Before, every ending
// said "ended"/"finished" in the same grey as a run that completed, only the note saying "exit: lost: …".
function endedFeed() {
  const text = state.status.state === "finished" ? "finished" : "ended";
  const exit = state.status.exit;
  if (exit === undefined || exit === null || exit === "completed") return { text, cls: "ended", age: 0 };
  return { text: `${text}: ${runOutcome(exit)}`, cls: "ended", failed: true, age: 0 };
}

// A summary's exit that is not "completed", as its outcome: the reason's head before its detail ("lost",
// "aborted", "interrupted", "error", "incomplete"; "disarmed by the operator at t=… s" without its time),
// cut short; any other JSON as its content (shortText).
function runOutcome(exit) {
  if (typeof exit !== "string") return shortText(exit).slice(0, 60);
  const head = exit.startsWith("disarmed by the operator") ? "disarmed by the operator" : exit.split(":")[0];
  return head.trim().slice(0, 60) || "not completed";
}

// Whether the newest row is what the run made last, so the feed's age is its age too: a live run's, and a run
// directory followed while another process writes it ("following", or "stopped being written": its writer
// gone). Before, only a live run's: a followed run whose writer hung or was killed showed its last row's
// board, power and attitude live, unmarked, the header alone saying "stale: run not growing".
function rowsComeAsMade() {
  return state.info.mode === "live" || ["following", "stopped"].includes(state.status.state);
}

// Whether the run ended without ever starting: an `ended` status (or the stream's end) with no `info`
// before it — a live run whose board or phone could not be opened. The hub sends a page without a run
// its statuses (hil/gcs/hub.py); before, it sent nothing until an `info` that never came.
function runFailedToStart() {
  return !state.info && (state.status.state === "ended" || state.ended);
}

// The feed before the run's description: a live station waiting for its run to start (its board and phone
// being opened: nothing is live yet, and it is not "loaded" either — it once said so, in green), or whose
// run failed to start, or one the page cannot reach.
function noRunFeed(heard) {
  if (runFailedToStart()) return { text: "the run failed to start", cls: "bad", age: 0 };
  if (!state.connected) return { text: state.refused || `connecting: nothing for ${heard.toFixed(1)} s`, cls: "bad", age: 0 };
  return { text: "waiting for the run", cls: "", age: 0 };
}

// ---------------------------------------------------------------- drawing
let lastRows = 0, frameRequested = false;

function invalidate() {
  state.dirty = true;
  if (!frameRequested) { frameRequested = true; requestAnimationFrame(frame); }
}

// Whether the page may command the run now, and if not, why (the uplink panel says it): a replay never; a
// live run only while its host answers — a silent or lost feed disables the buttons (a click would only
// fail), and they come back when the host does.
function uplinkState(feed) {
  const info = state.info;
  if (!info) {
    if (runFailedToStart()) return { on: false, why: `The run failed to start${state.status.exit ? ` (${shortText(state.status.exit)})` : ""}: no commands.` };
    return { on: false, why: state.connected ? "Waiting for the run: no commands yet." : "Connecting: no commands yet." };
  }
  if (info.mode !== "live") return { on: false, why: "Replay: no commands." };
  if (!info.uplink) return { on: false, why: "This run takes no commands (started without an uplink)." };
  if (feed.cls === "ended") return { on: false, why: `The run has ended${state.status.exit ? ` (${shortText(state.status.exit)})` : ""}: no commands.` };
  if (feed.cls === "stale" || feed.cls === "bad") return { on: false, why: `No word from the host (${feed.text}): commands are off until it answers.` };
  return { on: true, why: "" };
}

// The mode badge says what the page is looking at: a live run whose host answers, one whose host fell
// silent or went away, one that ended, or a replay.
function modeBadge(feed) {
  const info = state.info;
  if (!info) return runFailedToStart() ? { text: "no run", cls: "bad" } : { text: state.connected ? "waiting" : "connecting", cls: "" };
  if (info.mode !== "live") return { text: info.compare ? `compare: ${info.compare.length} runs` : "replay", cls: "replay" };
  const clock = info.clock || "run";
  if (feed.cls === "ended") return { text: `live run ended (${clock})`, cls: "ended" };
  if (state.history) return { text: `loading its history (${clock})`, cls: "" };
  if (feed.cls === "stale" || feed.cls === "bad") return { text: `host lost (${clock})`, cls: "bad" };
  return { text: `live (${clock})`, cls: "live" };
}

function showFeed() {
  const feed = feedState();
  const feedEl = $("feed");
  if (feedEl.textContent !== feed.text) feedEl.textContent = feed.text;  // unchanged: no relayout
  const feedClass = `badge ${feed.cls}${feed.failed ? " bad" : ""}`;  // a run that ended without completing
  if (feedEl.className !== feedClass) feedEl.className = feedClass;
  document.body.classList.toggle("feed-stale", feed.cls === "stale" || (feed.cls === "bad" && Boolean(state.info)));
  const mode = modeBadge(feed);
  setProp($("mode"), "textContent", mode.text);
  setProp($("mode"), "className", `badge ${mode.cls}`);
  const up = uplinkState(feed);
  uplink.enable(up.on, up.why);
  return feed;
}

let playClock = 0;
function frame(now) {
  frameRequested = false;
  if (state.playing && state.store) {
    const speed = Number($("speed").value);
    state.cursor += (now - playClock) / 1e3 * speed;
    playClock = now;
    if (state.cursor >= state.store.tLast) { state.cursor = state.store.tLast; state.playing = false; }
    else invalidate();  // the next frame moves on
  }
  const feed = showFeed();
  if (!state.dirty || !state.store) return;
  state.dirty = false;
  render(feed);
}

setInterval(() => { const cls = showFeed().cls; if (cls === "stale" || cls === "bad") invalidate(); }, CLOCK_MS);  // the ages shown grow

function render(feed) {
  const t0 = performance.now();
  const { store, info } = state;
  const hasRows = store.n > 0;
  if (state.follow && hasRows) state.cursor = store.tLast;
  setProp(timeline, "min", String(hasRows ? store.tFirst : 0));
  setProp(timeline, "max", String(hasRows ? store.tLast : 0));
  setProp(timeline, "value", String(Number.isFinite(state.cursor) ? state.cursor : 0));
  setProp($("play"), "textContent", state.playing ? "❚❚" : "▶");
  setProp($("follow"), "disabled", state.follow);
  setCell($("cursor-time"), hasRows ? `${fmt(state.cursor, 2)} s of ${fmt(store.tLast, 1)} s` : "no rows yet");
  const i = hasRows ? Math.max(store.indexAt(state.cursor), 0) : -1;
  if (hasRows) {
    const win = Number($("window").value);
    const i0 = win > 0 ? Math.max(store.indexAt(state.cursor - win), 0) : 0;
    state.plots.update(i0, i);
  }
  const t = store.col("t");
  const period = info.control_rate_hz ? 1 / info.control_rate_hz : 0.02;
  const rowGap = i > 0 && t[i] - t[i - 1] > 3 * period ? t[i] - t[i - 1] : 0;
  const feedAge = state.follow && rowsComeAsMade() ? feed.age : 0;
  const alarmAt = hasRows ? state.cursor : Infinity;
  const alarmColumns = state.alarms.activeColumns(alarmAt);
  const ended = feed.cls === "ended";
  const atEnd = state.follow || !(state.cursor < store.tLast);
  if (hasRows) drawPanels({ info, store, i, t: state.cursor, feedAge, rowGap, alarmColumns, ended, atEnd, summary: state.status.summary });
  const alarmsAge = state.follow && (feed.cls === "stale" || feed.cls === "bad") ? feedAge : 0;  // as of the newest row
  alarmPanel.draw(state.alarms, alarmAt, uplinkState(feed).on, alarmsAge);
  drawAttitude(i, feedAge, rowGap, ended && atEnd);
  drawEvents(store, hasRows ? state.cursor : Infinity);
  drawHistory(store.events, hasRows ? state.cursor : Infinity);
  stats.renders += 1;
  if (store.seen !== lastRows) { stats.dataRenders += 1; lastRows = store.seen; stats.renderTimes.push(performance.now()); }
  const now = performance.now();
  while (stats.renderTimes.length && stats.renderTimes[0] < now - 2000) stats.renderTimes.shift();
  stats.updateHz = stats.renderTimes.length / 2;
  stats.renderMs = performance.now() - t0;
  setProp($("stats"), "textContent", `${stats.updateHz.toFixed(0)} updates/s · ${store.n} rows${store.keepEvery > 1 ? ` (1 in ${store.keepEvery})` : ""} · ${(stats.bytes / 1e6).toFixed(1)} MB`);
}

// Assign only what changed: an unchanged assignment still costs the page a relayout or a repaint.
function setProp(el, name, value) {
  if (el[name] !== value) el[name] = value;
}

// A rotation vector (rad) as a target: three finite numbers (threeNumbers: a value JSON could not carry,
// 1e400, comes as null, hil/gcs/wire.py) whose length is one too (two components of 1.7e308: no angle).
function rotvec(r) {
  return threeNumbers(r) && Number.isFinite(Math.hypot(r[0], r[1], r[2])) ? r : null;
}

function targetAt(tc) {
  // The target: the scenario's, or the newest one a ground command set ("applied" carries target_r). An
  // applied command whose target_r is malformed leaves the target unknown from then on: the slew it
  // commanded went to an attitude the page cannot tell, and the older target would be a wrong one. Only the
  // command events are walked (commandEvents: each event scanned once), not every event of the run.
  let r = rotvec(state.store.droppedTarget === undefined ? state.info.target_r : state.store.droppedTarget);
  for (const e of commandEvents(state.store.events)) {
    if (e.t > tc) break;
    if (e.status === "applied" && "target_r" in e) r = rotvec(e.target_r);
  }
  return r ? rotvecToMatrix(r) : null;
}

// How old the estimate at row i is: the estimator moves on the phone's samples, so a silent phone leaves
// it where it was — the newest sample's age as of the row (the live phone_age_ms_* columns, the merger's
// per sensor) plus the feed's own age. A replay's telemetry has no phone ages: its rows' gaps alone say it.
function estimateAge(i, feedAge) {
  const ages = (state.info.phone || []).map((k) => state.store.value(`phone_age_ms_${k}`, i)).filter(Number.isFinite);
  return ages.length ? Math.min(...ages) / 1e3 + feedAge : 0;
}

// atRunEnd: the run has ended and the cursor is at its end (the attitude is the last row's, not live).
function drawAttitude(i, feedAge, rowGap, atRunEnd) {
  const { store, info } = state;
  const truth = ["true_rx", "true_ry", "true_rz"].map((c) => store.value(c, i));
  const est = ["est_rx", "est_ry", "est_rz"].map((c) => store.value(c, i));
  const useTruth = truth.every(Number.isFinite);
  const r = useTruth ? truth : est.every(Number.isFinite) ? est : null;
  const R = r ? rotvecToMatrix(r) : null;
  const target = targetAt(Number.isFinite(state.cursor) ? state.cursor : Infinity);
  const n = info.n_units || 0;
  const gamma = Array.from({ length: n }, (_, k) => store.value(`gimbal_angle_${k}`, i));
  const omega = Array.from({ length: n }, (_, k) => store.value(`rotor_speed_${k}`, i));
  // the attitude's age: the feed's, the gap before the row, and the estimate's own when it is the source
  // (a silent phone froze it: the attitude and the pointing error were drawn live, unchanged, for 4 s)
  const age = Math.max(feedAge, rowGap, r && !useTruth ? estimateAge(i, feedAge) : 0);
  const stale = age > (info.stale_after_s || 0.25) ? `stale: ${age.toFixed(1)} s old` : atRunEnd ? AT_RUN_END : "";
  view.draw({ R, target, units: info.units || [], gamma, omega, stale,
    nominal: (info.limits || {}).nominal_rotor_speed, maxSpeed: (info.limits || {}).max_rotor_speed });
  const canvas = $("view3d");
  canvas.dataset.attitude = r ? r.map((x) => x.toFixed(5)).join(",") : "";
  canvas.dataset.gimbal = gamma.map((x) => (Number.isFinite(x) ? x.toFixed(4) : "")).join(",");
  const eul = (M) => (M ? eulerZYX(M).map((x) => `${x.toFixed(1)}°`).join(", ") : "—");
  const staleAge = stale === AT_RUN_END ? AT_RUN_END : stale ? age : false;
  canvas.dataset.stale = stale;
  setCell($("attitude"), eul(R), staleAge);
  setCell($("target"), eul(target));
  setCell($("attitude-source"), r ? (useTruth ? "truth (simulated); the estimate is in the plots" : "estimate") : "—", staleAge);
  setCell($("point-err"), fmt(store.value("point_err_deg", i), 2, "°"), staleAge);
}

connect();
