// The time-series plots (uPlot): which columns each shows, the limits it marks, and how a window of the
// store becomes uPlot's data (at most MAX_POINTS per series, NaN as a gap).

const MAX_POINTS = 1200;
const UNIT_COLORS = ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#9a6324"];
const LIMIT = { stroke: "#c62828", dash: [5, 4], width: 1, points: { show: false } };

function perUnit(prefix, n, label) {
  return Array.from({ length: n }, (_, i) => ({ col: `${prefix}${i}`, label: `${label} ${i + 1}`, stroke: UNIT_COLORS[i % 8] }));
}

// Each plot: id, title, series [{col, label, stroke, dash}], limits (info) -> [{value, label}].
export function plotSpecs(info) {
  const n = info.n_units || 0, lim = info.limits || {};
  const specs = [
    { id: "pointing", title: "Pointing error (deg)", series: [
      { col: "point_err_deg", label: "pointing", stroke: "#e6194b" },
      { col: "track_err_deg", label: "tracking", stroke: "#4363d8" }],
      limits: lim.settle_deg ? [{ value: lim.settle_deg, label: "settle" }] : [] },
    { id: "est_att", title: "Estimator: attitude error, principal angle of R R̂ᵀ (deg)", series: [
      { col: "est_err_deg", label: "attitude error", stroke: "#911eb4" }] },
    { id: "est_rate", title: "Estimator: angular velocity error |Ω − Ω̂| (rad/s)", series: [
      { col: "rate_err", label: "rate error", stroke: "#f58231" }] },
    { id: "gimbal_angle", title: "Gimbal angles γ (rad) — multi-turn, no angle limit", series: perUnit("gimbal_angle_", n, "γ") },
    { id: "gimbal_rate", title: "Gimbal rates γ̇ (rad/s)", series: perUnit("gimbal_rate_", n, "γ̇"),
      limits: lim.max_gimbal_rate ? [{ value: lim.max_gimbal_rate, label: "+max" }, { value: -lim.max_gimbal_rate, label: "−max" }] : [] },
    { id: "rotor", title: "Rotor speeds Ω (rad/s)", series: perUnit("rotor_speed_", n, "Ω"),
      limits: [lim.min_rotor_speed && { value: lim.min_rotor_speed, label: "min" },
               lim.max_rotor_speed && { value: lim.max_rotor_speed, label: "max" }].filter(Boolean) },
    { id: "pulses", title: "Pulse widths (µs)", series: [
      ...perUnit("pulse_gimbal_", n, "gimbal").map((s) => ({ ...s })),
      ...perUnit("pulse_rotor_", n, "rotor").map((s) => ({ ...s, dash: [4, 3] }))] },
    { id: "delta", title: "Singularity measure δ", series: [{ col: "delta", label: "δ", stroke: "#1d232b" }] },
    { id: "power", title: "Battery and UBEC rail", series: [
      { col: "battery_v", label: "battery V", stroke: "#3cb44b" },
      { col: "ubec_v", label: "UBEC V", stroke: "#4363d8" },
      { col: "battery_a", label: "battery A", stroke: "#f58231", dash: [4, 3] }] },
  ];
  return specs;
}

export class Plots {
  // onShown: called when a plot scrolls into view (it was not redrawn while hidden).
  constructor(container, info, store, onShown = () => {}) {
    this.container = container;
    this.store = store;
    this.charts = [];
    this.visibility = new IntersectionObserver((entries) => {
      for (const entry of entries) {
        const c = this.charts.find((x) => x.box === entry.target);
        if (c) c.visible = entry.isIntersecting;
      }
      onShown();
    });
    container.innerHTML = "";
    for (const spec of plotSpecs(info)) {
      const series = spec.series.filter((s) => store.has(s.col));
      if (!series.length) continue;
      const box = document.createElement("div");
      box.className = "plot"; box.id = `plot-${spec.id}`;
      box.innerHTML = `<h3>${spec.title}</h3>`;
      container.appendChild(box);
      const limits = spec.limits || [];
      const opts = {
        width: Math.max(box.clientWidth - 8, 200), height: 150,
        scales: { x: { time: false } },
        legend: { show: true, live: false },
        cursor: { drag: { x: false, y: false } },
        axes: [{ size: 28 }, { size: 52 }],
        series: [{ label: "t (s)" },
          ...series.map((s) => ({ label: s.label, stroke: s.stroke, width: 1.5, dash: s.dash, points: { show: false } })),
          ...limits.map((l) => ({ ...LIMIT, label: l.label }))],
      };
      const chart = new uPlot(opts, [[], ...series.map(() => []), ...limits.map(() => [])], box);
      this.charts.push({ spec, series, limits, chart, box, visible: true });
      this.visibility.observe(box);
    }
    this.resize = () => { for (const c of this.charts) c.chart.setSize({ width: Math.max(c.box.clientWidth - 8, 200), height: 150 }); };
    window.addEventListener("resize", this.resize);
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
    const take = (col) => {
      const out = [];
      for (let i = i0; i <= i1; i += stride) { const v = col[i]; out.push(Number.isFinite(v) ? v : null); }
      return out;
    };
    const x = take(store.col("t"));
    for (const c of this.charts) {
      if (!c.visible) continue;
      const data = [x, ...c.series.map((s) => take(store.col(s.col))), ...c.limits.map((l) => x.map(() => l.value))];
      c.chart.setData(data);
      const last = data[1][data[1].length - 1];
      c.box.dataset.points = String(x.length);
      c.box.dataset.lastT = String(x[x.length - 1]);
      c.box.dataset.last = last === null ? "" : String(last);
    }
  }
}
