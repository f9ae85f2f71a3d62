// The page's copy of the run: telemetry as columns of Float64Array (NaN = no value), events and link
// snapshots in time order. Bounded: past MAX_ROWS rows every other row is dropped (the resolution halves,
// the whole run stays), and from then on only every 2nd (4th, ...) row is kept; the link snapshots alike past
// MAX_LINK, the newest always kept (the panel shows it while following).

export const MAX_ROWS = 250000;
// A live run sends a link snapshot every 0.2 s of run time (hil/gcs/live.py, LINK_PERIOD_S), each an object
// of some thirty figures: kept whole, a page left open on a day's run held 430 000 of them (hundreds of MB).
export const MAX_LINK = 20000;
// Events kept: a run that floods them (a phone on the port logged per message, a script's refused requests,
// a hostile events.jsonl of millions of lines) grew the page's memory without bound. Past MAX_EVENTS the
// oldest are dropped, down to 3/4 of it at a time (each drop a copy, so rarely), counted and said on the page
// (eventsDropped, eventsFrom); the target an applied slew among them set is kept (droppedTarget).
export const MAX_EVENTS = 200000;

// An event whose `t` is no finite number (missing, null, "1e9", [1e9]: a run directory's events are any JSON),
// as the store holds it: at the time it is placed at (the event before it; -Infinity before any), its own
// `t` kept as "t (as sent)" (the events table shows it). Kept as it came, the page's walks over the events —
// `if (e.t > t) break` — stopped at it wherever JavaScript's comparison made "1e9" or [1e9] later than the
// cursor: one such record hid every later command from the command history and the target.
function placedAt(e, t) {
  const out = { ...e, t };
  if (Object.hasOwn(e, "t")) out["t (as sent)"] = e.t;
  return out;
}

export class Store {
  constructor(columns) {
    this.columns = columns;
    this.index = Object.fromEntries(columns.map((c, i) => [c, i]));
    this.capacity = 4096;
    this.n = 0;
    this.data = columns.map(() => new Float64Array(this.capacity));
    this.keepEvery = 1;  // rows kept: 1 in keepEvery (after decimation)
    this.seen = 0;       // rows received
    this.events = [];
    this.eventKeys = [];  // each event's place in time (pushEvents)
    this.eventsDropped = 0;  // the oldest events dropped past MAX_EVENTS (boundEvents)
    this.eventsFrom = -Infinity;  // the time of the oldest event kept once some were dropped
    this.droppedTarget = undefined;  // target_r of the newest applied command dropped (undefined: none)
    this.link = [];
    this.linkEvery = 1;   // link snapshots kept: 1 in linkEvery, and the newest (pushLink)
    this.linkSeen = 0;    // link snapshots received
    this.linkNewest = false;  // whether the last one held is the newest only, not one of the 1 in linkEvery
  }

  has(name) { return name in this.index; }

  col(name) {
    const i = this.index[name];
    return i === undefined ? null : this.data[i];
  }

  pushRows(rows) {
    for (const row of rows) {
      this.seen += 1;
      if ((this.seen - 1) % this.keepEvery) continue;
      if (this.n === this.capacity) this.grow();
      const n = this.n;
      for (let i = 0; i < this.data.length; i++) {
        const v = row[i];
        this.data[i][n] = v === null || v === undefined ? NaN : v;
      }
      this.n = n + 1;
    }
  }

  grow() {
    if (this.capacity >= MAX_ROWS) {  // decimate in place: keep the even rows
      const half = Math.ceil(this.n / 2);
      for (const col of this.data) for (let i = 0; i < half; i++) col[i] = col[2 * i];
      this.n = half;
      this.keepEvery *= 2;
      return;
    }
    this.capacity = Math.min(this.capacity * 2, MAX_ROWS);
    this.data = this.data.map((old) => { const a = new Float64Array(this.capacity); a.set(old); return a; });
  }

  // Events kept in time order (ties: in the order they came). An event without a finite time goes with
  // the one that came before it. A batch in order after the last is appended; one that is not (a run
  // directory's events out of order: damaged, spliced, hostile) is sorted and merged in one pass — each
  // event walked back to its place and spliced in was O(n) apiece: 100 000 events in reverse order froze
  // the page for 8 s, 400 000 for minutes.
  pushEvents(events) {
    if (!events.length) return;
    let prev = this.eventKeys.length ? this.eventKeys[this.eventKeys.length - 1] : -Infinity;
    const batch = events.map((e, i) => {
      const timed = typeof e.t === "number" && Number.isFinite(e.t);
      prev = timed ? e.t : prev;
      return { e: timed ? e : placedAt(e, prev), k: prev, i };
    });
    let sorted = true;
    for (let j = 1; j < batch.length && sorted; j++) sorted = batch[j - 1].k <= batch[j].k;
    if (!sorted) batch.sort((a, b) => a.k - b.k || a.i - b.i);
    const last = this.eventKeys.length ? this.eventKeys[this.eventKeys.length - 1] : -Infinity;
    if (batch[0].k >= last) {
      for (const b of batch) { this.events.push(b.e); this.eventKeys.push(b.k); }
      this.boundEvents();
      return;
    }
    const events0 = this.events, keys0 = this.eventKeys, n = events0.length;
    const outE = new Array(n + batch.length), outK = new Array(n + batch.length);
    let a = 0, b = 0, o = 0;
    while (a < n || b < batch.length) {
      if (b >= batch.length || (a < n && keys0[a] <= batch[b].k)) { outE[o] = events0[a]; outK[o++] = keys0[a++]; }
      else { outE[o] = batch[b].e; outK[o++] = batch[b++].k; }
    }
    this.events = outE;
    this.eventKeys = outK;
    this.boundEvents();
  }

  // Past MAX_EVENTS, the oldest events go (down to 3/4 of it): counted, their last time kept for the page to
  // say where its events start, and the target the newest applied command among them set (app.js targetAt
  // starts from it: else a dropped slew's target would read as the scenario's). A new array, so the command
  // scan (commands.js commandEvents) starts afresh.
  boundEvents() {
    const n = this.events.length;
    if (n <= MAX_EVENTS) return;
    const drop = n - Math.floor(MAX_EVENTS * 3 / 4);
    for (let i = 0; i < drop; i++) {
      const e = this.events[i];
      if (e.kind === "command" && e.status === "applied" && "target_r" in e) this.droppedTarget = e.target_r;
    }
    this.events = this.events.slice(drop);
    this.eventKeys = this.eventKeys.slice(drop);
    this.eventsDropped += drop;
    this.eventsFrom = this.eventKeys[0];
  }

  // Link snapshots in time order, bounded as the rows are (MAX_LINK): past it every other one is dropped and
  // from then on 1 in 2 (4, ...) kept — and the newest one always, replaced by the next.
  pushLink(snapshots) {
    for (const s of snapshots) {
      this.linkSeen += 1;
      if (this.linkNewest) this.link.pop();
      this.link.push(s);
      this.linkNewest = (this.linkSeen - 1) % this.linkEvery !== 0;
      if (!this.linkNewest && this.link.length > MAX_LINK) {  // the one pushed is the (MAX_LINK)th kept: even
        this.link = this.link.filter((_, i) => i % 2 === 0);
        this.linkEvery *= 2;
      }
    }
  }

  get tFirst() { return this.n ? this.data[0][0] : NaN; }
  get tLast() { return this.n ? this.data[0][this.n - 1] : NaN; }

  // Index of the last row with t <= time (-1 if none).
  indexAt(time) {
    const t = this.data[0];
    let lo = 0, hi = this.n - 1, found = -1;
    while (lo <= hi) {
      const mid = (lo + hi) >> 1;
      if (t[mid] <= time) { found = mid; lo = mid + 1; } else hi = mid - 1;
    }
    return found;
  }

  value(name, i) {
    const c = this.col(name);
    return c === null || i < 0 ? NaN : c[i];
  }

  // The newest link snapshot at or before time.
  linkAt(time) {
    for (let i = this.link.length - 1; i >= 0; i--) if (!(this.link[i].t > time)) return this.link[i];
    return null;
  }
}
