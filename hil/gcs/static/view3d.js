// The spacecraft in 3D on a plain 2D canvas (orthographic, painter's order): the 1U bus as a box with its
// body axes (x red, y green, z blue), the target attitude's axes dashed, and each VSCMG unit as a rotor
// disc on its gimbal axis — turned by its gimbal angle, coloured and its spin arrow scaled by its rotor
// speed. The view looks at the inertial frame (ENU: x east, y north, z up); drag to turn it.
// No 3D library: a box, axes and a few discs are a few dozen lines of projection, and canvas 2D draws
// without a GPU (headless CI included).

export function rotvecToMatrix(r) {
  const th = Math.hypot(r[0], r[1], r[2]);
  if (!(th > 1e-12)) return [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  const k = [r[0] / th, r[1] / th, r[2] / th], c = Math.cos(th), s = Math.sin(th), v = 1 - c;
  return [
    [c + k[0] * k[0] * v, k[0] * k[1] * v - k[2] * s, k[0] * k[2] * v + k[1] * s],
    [k[1] * k[0] * v + k[2] * s, c + k[1] * k[1] * v, k[1] * k[2] * v - k[0] * s],
    [k[2] * k[0] * v - k[1] * s, k[2] * k[1] * v + k[0] * s, c + k[2] * k[2] * v],
  ];
}

// Roll, pitch, yaw (deg) of R = Rz(yaw) Ry(pitch) Rx(roll), body -> inertial.
export function eulerZYX(R) {
  const d = 180 / Math.PI;
  const pitch = Math.asin(Math.max(-1, Math.min(1, -R[2][0])));
  return [Math.atan2(R[2][1], R[2][2]) * d, pitch * d, Math.atan2(R[1][0], R[0][0]) * d];
}

const mul = (R, v) => [
  R[0][0] * v[0] + R[0][1] * v[1] + R[0][2] * v[2],
  R[1][0] * v[0] + R[1][1] * v[1] + R[1][2] * v[2],
  R[2][0] * v[0] + R[2][1] * v[1] + R[2][2] * v[2],
];
const add = (a, b, s = 1) => [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.hypot(a[0], a[1], a[2]);

const AXIS_COLORS = ["#ff5a5a", "#4cd964", "#4da3ff"];

export class View3D {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.azimuth = -0.65;   // rad, about the inertial z axis
    this.elevation = 0.42;  // rad above the horizon
    this.frames = 0;
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      this.azimuth -= (e.clientX - drag[0]) * 0.01;
      this.elevation = Math.max(-1.5, Math.min(1.5, this.elevation + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      if (this.last) this.draw(this.last);
    });
  }

  // Inertial point -> [screen x, screen y, depth (larger = nearer)].
  project(p) {
    const ca = Math.cos(this.azimuth), sa = Math.sin(this.azimuth);
    const ce = Math.cos(this.elevation), se = Math.sin(this.elevation);
    const x = ca * p[0] - sa * p[1];
    const yh = sa * p[0] + ca * p[1];  // horizontal, away from the viewer
    const y = ce * p[2] - se * yh;
    const depth = -(ce * yh + se * p[2]);
    const { width: w, height: h } = this.canvas;
    const scale = Math.min(w, h) * 0.36;
    return [w / 2 + x * scale, h / 2 - y * scale, depth];
  }

  line(a, b, color, width = 2, dash = []) {
    const ctx = this.ctx, p = this.project(a), q = this.project(b);
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.setLineDash(dash);
    ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
    ctx.setLineDash([]);
  }

  label(p, text, color) {
    const s = this.project(p);
    this.ctx.fillStyle = color; this.ctx.font = "12px system-ui, sans-serif";
    this.ctx.fillText(text, s[0] + 3, s[1] - 3);
  }

  // scene: {R, target (matrix or null), units: [{g, s0, t0, p}], gamma: [], omega: [], nominal, maxSpeed, stale}
  draw(scene) {
    this.last = scene;
    this.frames += 1;
    const { ctx, canvas } = this;
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    // inertial axes, small, bottom left
    const o = [-1.25, -1.25, -1.05];
    ["E", "N", "U"].forEach((name, i) => {
      const e = [0, 0, 0]; e[i] = 0.3;
      this.line(o, add(o, e), "#66707d", 1.5); this.label(add(o, e), name, "#8a94a2");
    });
    if (!scene.R) {
      ctx.fillStyle = "#8a94a2"; ctx.font = "14px system-ui"; ctx.fillText("no attitude yet", 20, 30);
      return;
    }
    const R = scene.R;
    if (scene.target) {
      for (let i = 0; i < 3; i++) {
        const e = [0, 0, 0]; e[i] = 1.05;
        this.line([0, 0, 0], mul(scene.target, e), AXIS_COLORS[i], 1.5, [6, 5]);
      }
      this.label(mul(scene.target, [1.1, 0, 0]), "target", "#c8ced6");
    }
    // box: back faces, then units, then front faces and edges
    const h = 0.5, faces = [];
    for (let axis = 0; axis < 3; axis++) for (const sign of [-1, 1]) {
      const n = [0, 0, 0]; n[axis] = sign;
      const u = [0, 0, 0]; u[(axis + 1) % 3] = h;
      const v = [0, 0, 0]; v[(axis + 2) % 3] = h;
      const c = n.map((x) => x * h);
      const corners = [add(add(c, u), v), add(add(c, u), v, -1), add(add(c, u, -1), v, -1), add(add(c, u, -1), v)];
      const world = corners.map((p) => mul(R, p));
      const depth = this.project(mul(R, c))[2] - this.project([0, 0, 0])[2];
      faces.push({ world, front: depth > 0, axis, sign });
    }
    const drawFace = (f, alpha) => {
      const pts = f.world.map((p) => this.project(p));
      ctx.beginPath(); ctx.moveTo(pts[0][0], pts[0][1]);
      for (const p of pts.slice(1)) ctx.lineTo(p[0], p[1]);
      ctx.closePath();
      ctx.fillStyle = `rgba(170, 185, 205, ${alpha})`; ctx.fill();
      ctx.strokeStyle = scene.stale ? "#5a6270" : "#c8d2e0"; ctx.lineWidth = 1; ctx.stroke();
    };
    faces.filter((f) => !f.front).forEach((f) => drawFace(f, 0.10));
    this.drawUnits(scene, R);
    faces.filter((f) => f.front).forEach((f) => drawFace(f, 0.16));
    for (let i = 0; i < 3; i++) {
      const e = [0, 0, 0]; e[i] = 0.95;
      this.line([0, 0, 0], mul(R, e), AXIS_COLORS[i], 3);
      this.label(mul(R, e), "xyz"[i], AXIS_COLORS[i]);
    }
    if (scene.stale) {
      ctx.fillStyle = "rgba(255, 190, 80, 0.95)"; ctx.font = "bold 14px system-ui";
      ctx.fillText(scene.stale, 12, canvas.height - 12);
    }
    this.canvas.dataset.frames = String(this.frames);
  }

  drawUnits(scene, R) {
    const units = scene.units || [];
    const spread = units.some((u, i) => units.some((w, j) => j > i && norm(add(u.p, w.p, -1)) > 1e-3));
    const items = units.map((u, i) => {
      const pos = spread ? u.p.map((x) => x / Math.max(...units.map((w) => norm(w.p))) * 0.3) : u.g.map((x) => x * 0.3);
      const gam = scene.gamma[i], om = scene.omega[i];
      const ok = Number.isFinite(gam) && Number.isFinite(om);
      const c = Math.cos(ok ? gam : 0), s = Math.sin(ok ? gam : 0);
      const spin = add(u.s0.map((x) => x * c), u.t0.map((x) => x * s));
      return { i, u, pos, spin, om, ok, depth: this.project(mul(R, pos))[2] };
    }).sort((a, b) => a.depth - b.depth);
    const ctx = this.ctx;
    for (const it of items) {
      const { u, pos, spin, om, ok } = it;
      this.line(mul(R, add(pos, u.g, -0.2)), mul(R, add(pos, u.g, 0.2)), "#7d8794", 2);
      const a = u.g, b = cross(spin, u.g), rad = 0.15;
      ctx.beginPath();
      for (let k = 0; k <= 24; k++) {
        const th = (k / 24) * 2 * Math.PI;
        const p = this.project(mul(R, add(add(pos, a, rad * Math.cos(th)), b, rad * Math.sin(th))));
        if (k === 0) ctx.moveTo(p[0], p[1]); else ctx.lineTo(p[0], p[1]);
      }
      const frac = ok && scene.maxSpeed > 0 ? Math.min(Math.abs(om) / scene.maxSpeed, 1) : 0;
      ctx.fillStyle = ok ? `hsla(${220 - 220 * frac}, 80%, 55%, 0.75)` : "rgba(120,120,120,0.4)";
      ctx.strokeStyle = "#e8edf3"; ctx.lineWidth = 1; ctx.fill(); ctx.stroke();
      const len = 0.08 + 0.22 * (ok && scene.nominal > 0 ? Math.min(Math.abs(om) / scene.nominal, 1.6) : 0);
      const tip = add(pos, spin, Math.sign(om || 1) * len);
      this.line(mul(R, pos), mul(R, tip), "#ffd166", 2);
      this.label(mul(R, tip), String(it.i + 1), "#ffd166");
    }
  }
}
