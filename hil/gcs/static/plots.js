// The time-series plots (uPlot): which columns each shows (in which unit), the limits it marks, the
// commands and events it marks (markers.js), its PNG and CSV exports, and how a window of the store becomes
// uPlot's data (at most MAX_POINTS per series, NaN as a gap).

import { runMarkers, markerPlugin } from "./markers.js";
import { download, downloadCsv, safeName } from "./exports.js";

const MAX_POINTS = 1200;
const UNIT_COLORS = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324"];
const LIMIT_COLORS = { warning: "#c77c02", critical: "#c62828" };

function perUnit(prefix, n, label) {
  return Array.from({ length: n }, (_, i) => ({ col: `${prefix}${i}`, label: `${label} ${i + 1}`, stroke: UNIT_COLORS[i % 8] }));
}

// The horizontal lines a plot draws: the thresholds of the run's alarms (info.alarms) on its columns, one
// line per distinct threshold (the units share theirs), ±value for a limit on |x|.
export function limitLines(info, columns) {
  const lines = new Map();
  for (const a of info.alarms || []) {
    if (!columns.includes(a.column) || a.op === "equals" || a.op === "event") continue;
    const values = a.op === "abs_above" ? [a.value, -a.value] : [a.value];
    for (const value of values) {
      const key = `${value}`;
      if (lines.has(key)) continue;
      const word = a.op === "below" ? "min" : "max";
      lines.set(key, { value, severity: a.severity, label: `${a.label.replace(/^unit \d+ /, "")} ${value < 0 ? "−" : ""}${word}` });
    }
  }
  return [...lines.values()];
}

// Each plot: id, title, series [{col, label, stroke, dash}]; its limit lines come from limitLines. n: the
// units the per-unit plots have series for (the run's; of runs compared, the most any of them has).
export function plotSpecs(info, n = info.n_units || 0) {
  const specs = [
    { id: "pointing", title: "Pointing error (deg)", series: [
      { col: "point_err_deg", label: "pointing", stroke: "#e6194b" },
      { col: "track_err_deg", label: "tracking", stroke: "#4363d8" }] },
    { id: "est_att", title: "Estimator: attitude error, principal angle of R R̂ᵀ (deg)", series: [
      { col: "est_err_deg", label: "attitude error", stroke: "#911eb4" }] },
    { id: "est_rate", title: "Estimator: angular velocity error |Ω − Ω̂| (rad/s)", series: [
      { col: "rate_err", label: "rate error", stroke: "#f58231" }] },
    { id: "gimbal_angle", title: "Gimbal angles γ (°) — multi-turn, no angle limit",
      series: perUnit("gimbal_angle_", n, "γ").map((s) => ({ ...s, scale: 180 / Math.PI })) },
    { id: "gimbal_rate", title: "Gimbal rates γ̇ (rad/s)", series: perUnit("gimbal_rate_", n, "γ̇") },
    { id: "rotor", title: "Rotor speeds Ω (rad/s)", series: perUnit("rotor_speed_", n, "Ω") },
    { id: "pulses", title: "Pulse widths (µs)", series: [
      ...perUnit("pulse_gimbal_", n, "gimbal").map((s) => ({ ...s })),
      ...perUnit("pulse_rotor_", n, "rotor").map((s) => ({ ...s, dash: [4, 3] }))] },
    { id: "delta", title: "Singularity measure δ", series: [{ col: "delta", label: "δ", stroke: "#1d232b" }] },
    { id: "power", title: "Battery and UBEC rail", series: [
      { col: "battery_v", label: "battery V", stroke: "#3cb44b" },
      { col: "ubec_v", label: "UBEC V", stroke: "#4363d8" },
      { col: "battery_a", label: "battery A", stroke: "#f58231", dash: [4, 3] }] },
    { id: "ages", title: "Link: the board's age of the host's frames, the host's of the board's telemetry (ms)", series: [
      { col: "link_age_ms", label: "board: last host frame", stroke: "#4363d8" },
      { col: "tel_age_ms", label: "host: last telemetry", stroke: "#e6194b" }] },
  ];
  return specs;
}

const RUN_COLORS = ["#e6194b", "#4363d8", "#3cb44b", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324"];
const RUN_DASHES = [undefined, [6, 3], [2, 2], [9, 3, 2, 3], [1, 3], [12, 4]];

// How many units a run's telemetry has: its gimbal_angle_<i> columns (hil/gcs/info.py, units_from_columns).
function unitsOf(columns) {
  return columns.filter((c) => /^gimbal_angle_\d+$/.test(c)).length;
}

// Runs compared (overlays: [{name, store}]): every series of a plot once per run, coloured by run (the
// series within a run told apart by their dash), labelled "series · run" — the legend by run name.
function seriesPerRun(specSeries, runs) {
  const out = [];
  runs.forEach((run, r) => {
    specSeries.filter((s) => run.store.has(s.col)).forEach((s, j) => {
      out.push({ ...s, label: `${s.label} · ${run.name}`, stroke: RUN_COLORS[r % RUN_COLORS.length],
        dash: RUN_DASHES[j % RUN_DASHES.length], store: run.store });
    });
  });
  return out;
}

// Column col of another run's store at the times xs (increasing; null: none): the value of its row at or
// before each time (sample and hold), none before its first row or after its last.
function sampleAt(store, col, xs, scale) {
  const t = store.col("t"), v = store.col(col), n = store.n, out = new Array(xs.length);
  let j = 0;
  for (let k = 0; k < xs.length; k++) {
    const x = xs[k];
    if (x === null || !n || x < t[0] || x > t[n - 1] + 1e-9) { out[k] = null; continue; }
    while (j + 1 < n && t[j + 1] <= x) j++;
    out[k] = Number.isFinite(v[j]) ? v[j] * scale : null;
  }
  return out;
}

export class Plots {
  // onShown: called when a plot scrolls into view (it was not redrawn while hidden); overlays: other runs
  // compared with this one ([{name, store}], hil/gcs/compare.py), drawn on this run's time axis.
  constructor(container, info, store, onShown = () => {}, overlays = []) {
    this.container = container;
    this.store = store;
    const runs = overlays.length ? [{ name: info.run, store }, ...overlays] : null;
    this.charts = [];
    this.markers = [];
    this.markedEvents = -1;  // the store's event count the markers were made from
    this.runName = safeName(info.run);
    this.visibility = new IntersectionObserver((entries) => {
      for (const entry of entries) {
        const c = this.charts.find((x) => x.box === entry.target);
        if (c) c.visible = entry.isIntersecting;
      }
      onShown();
    });
    container.innerHTML = "";
    const style = getComputedStyle(document.body);
    const ink = style.getPropertyValue("--ink").trim() || "#1d232b";
    const grid = style.getPropertyValue("--grid").trim() || "rgba(0,0,0,0.07)";
    // runs compared may have more units than this one (the testbed's 3 and the CubeSat's 4): each one drawn,
    // not only this run's count of them, which left the 4th unit of a CubeSat compared out without a word
    const units = Math.max(info.n_units || 0, ...overlays.map((o) => unitsOf(o.store.columns)));
    for (const spec of plotSpecs(info, units)) {
      const series = runs ? seriesPerRun(spec.series, runs) : spec.series.filter((s) => store.has(s.col));
      if (!series.length) continue;
      const box = document.createElement("div");
      box.className = "plot"; box.id = `plot-${spec.id}`;
      box.innerHTML = `<h3><span class="title"></span><span class="exports"><button data-export="png" title="this plot as a PNG">PNG</button><button data-export="csv" title="the points shown, as CSV">CSV</button></span></h3>`;
      box.querySelector(".title").textContent = spec.title;
      container.appendChild(box);
      const limits = limitLines(info, [...new Set(series.map((s) => s.col))]);
      const opts = {
        width: Math.max(box.clientWidth - 8, 200), height: 150,
        scales: { x: { time: false } },
        legend: { show: true, live: false },
        cursor: { drag: { x: false, y: false } },
        axes: [{ size: 28, stroke: ink, grid: { stroke: grid }, ticks: { stroke: grid } },
               { size: 52, stroke: ink, grid: { stroke: grid }, ticks: { stroke: grid } }],
        plugins: [markerPlugin(() => this.markers, box)],
        series: [{ label: "t (s)" },
          ...series.map((s) => ({ label: s.label, stroke: s.stroke, width: 1.5, dash: s.dash, points: { show: false } })),
          ...limits.map((l) => ({ label: l.label, stroke: LIMIT_COLORS[l.severity] || LIMIT_COLORS.critical, dash: [5, 4], width: 1, points: { show: false } }))],
      };
      const chart = new uPlot(opts, [[], ...series.map(() => []), ...limits.map(() => [])], box);
      box.dataset.limits = limits.map((l) => `${l.label}=${l.value}`).join(";");
      const entry = { spec, series, limits, chart, box, visible: true };
      this.charts.push(entry);
      box.querySelector("[data-export=png]").addEventListener("click", () => this.exportPng(entry));
      box.querySelector("[data-export=csv]").addEventListener("click", () => this.exportCsv(entry));
      this.visibility.observe(box);
    }
    this.resize = () => { for (const c of this.charts) c.chart.setSize({ width: Math.max(c.box.clientWidth - 8, 200), height: 150 }); };
    window.addEventListener("resize", this.resize);
  }

  // The plot as drawn (axes, lines, limits, markers) under its title, as a PNG.
  exportPng(c) {
    const src = c.chart.ctx.canvas, pad = 24 * devicePixelRatio;
    const out = document.createElement("canvas");
    out.width = src.width; out.height = src.height + pad;
    const ctx = out.getContext("2d");
    const style = getComputedStyle(document.body);
    ctx.fillStyle = style.getPropertyValue("--card").trim() || "#fff";
    ctx.fillRect(0, 0, out.width, out.height);
    ctx.fillStyle = style.getPropertyValue("--ink").trim() || "#000";
    ctx.font = `600 ${Math.round(12 * devicePixelRatio)}px system-ui, sans-serif`;
    ctx.fillText(c.spec.title, 6 * devicePixelRatio, 16 * devicePixelRatio);
    ctx.drawImage(src, 0, pad);
    out.toBlob((blob) => download(blob, `${this.runName}-${c.spec.id}.png`), "image/png");
  }

  // The points the plot shows (its window, thinned as drawn), one row per time, as CSV.
  exportCsv(c) {
    const data = c.chart.data, n = c.series.length;
    const header = ["t (s)", ...c.series.map((s) => s.label)];
    const rows = data[0].map((t, k) => [t, ...Array.from({ length: n }, (_, j) => data[j + 1][k])]);
    downloadCsv(`${this.runName}-${c.spec.id}.csv`, header, rows);
  }

  destroy() {
    window.removeEventListener("resize", this.resize);
    this.visibility.disconnect();
    for (const c of this.charts) c.chart.destroy();
    this.charts = [];
  }

  // Show rows i0..i1 (inclusive) of the store in the plots in view (the page's redraws are its main cost
  // to the machine the run shares it with).
  update(i0, i1) {
    const store = this.store, count = i1 - i0 + 1;
    if (count <= 0) return;
    const stride = Math.max(1, Math.ceil(count / MAX_POINTS));
    const take = (col, scale = 1) => {
      const out = [];
      for (let i = i0; i <= i1; i += stride) { const v = col[i]; out.push(Number.isFinite(v) ? v * scale : null); }
      return out;
    };
    if (store.events.length !== this.markedEvents) {
      this.markedEvents = store.events.length;
      this.markers = runMarkers(store.events);
    }
    const x = take(store.col("t"));
    for (const c of this.charts) {
      if (!c.visible) continue;
      const values = (s) => (s.store && s.store !== store ? sampleAt(s.store, s.col, x, s.scale || 1) : take(store.col(s.col), s.scale || 1));
      const data = [x, ...c.series.map(values), ...c.limits.map((l) => x.map(() => l.value))];
      c.chart.setData(data);
      const last = data[1][data[1].length - 1];
      c.box.dataset.points = String(x.length);
      c.box.dataset.lastT = String(x[x.length - 1]);
      c.box.dataset.last = last === null ? "" : String(last);
    }
  }
}
