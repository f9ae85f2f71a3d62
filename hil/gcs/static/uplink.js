// The uplink panel: a command needs a second click to confirm (arm, disarm, abort, slew), goes out as a
// JSON POST with the token, and its line in the command log follows what the run says about it (its
// "command" events: sent -> acked / nacked / failed, or applied / refused).

import { $, shortText } from "./panels.js";

const CONFIRM_MS = 4000;
const SLEW_AXES = ["roll", "pitch", "yaw"];
const GCS_ORIGIN = "gcs";  // the origin of the server's command records (hil/gcs/uplink.py, parse_command)
// The command log keeps this page's newest LOG_MAX lines (the command history below has every command of
// the run); before, each click added a line for good: a page left open on a long run grew without bound.
export const LOG_MAX = 100;
// The newest "command" events kept for commands whose POST has not been answered yet (any sender's of
// origin "gcs": another page's too), at most this many, the oldest forgotten first.
const LATEST_MAX = 1000;

// The number typed in a number field, or null when there is none: an empty field, or text the browser
// cannot read as a number ("1e", "-", "1e400": its value is then ""), is no angle. Number("") is 0: such a
// field once sent a slew to 0° that the operator never typed. The range is the server's to check
// (hil/gcs/uplink.py, ANGLE_RANGE), whose refusal the log shows.
function typedNumber(input) {
  if (input.validity.badInput || input.value.trim() === "") return null;
  const value = Number(input.value);
  return Number.isFinite(value) ? value : null;
}

export class Uplink {
  constructor(token) {
    this.token = token;
    this.enabled = false;
    this.items = new Map();  // id -> <li>
    this.latest = new Map();  // id -> the newest "command" event (it may come before the POST's answer)
    for (const button of document.querySelectorAll("#uplink button[data-command]")) {
      button.addEventListener("click", () => this.click(button));
    }
  }

  // on: commands allowed; why: what the panel says when they are not (a replay, an ended run, a host
  // that does not answer). Touches the DOM only when something changed (called 4 times a second).
  enable(on, why = "") {
    const off = $("uplink-off");
    if (this.enabled === on && off.textContent === why) return;
    this.enabled = on;
    off.hidden = on;
    off.textContent = why;
    for (const b of document.querySelectorAll("#uplink .buttons button, #uplink .slew button, #uplink .slew input")) {
      b.disabled = !on;
      if (!on) this.reset(b);
    }
  }

  click(button) {
    if (!this.enabled) return;
    if (button.dataset.confirm && !button.classList.contains("confirming")) {
      button.dataset.label = button.dataset.label || button.textContent;
      button.classList.add("confirming");
      button.textContent = `Confirm ${button.dataset.label.toLowerCase()}?`;
      button._timer = setTimeout(() => this.reset(button), CONFIRM_MS);
      return;
    }
    this.reset(button);
    const body = { command: button.dataset.command };
    if (body.command === "slew") {
      const unread = [];
      for (const axis of SLEW_AXES) {
        const angle = typedNumber($(`slew-${axis}`));
        if (angle === null) unread.push(axis);
        body[`${axis}_deg`] = angle;
      }
      if (unread.length) {
        this.log("error", `${describe(body)}: not sent, ${unread.join(", ")} not a number of degrees`);
        return;
      }
    }
    this.send(body);
  }

  // A line in the command log, newest first; past LOG_MAX lines the oldest goes, and with it its command's
  // place in `items` (its later statuses have no line to update).
  log(status, text) {
    const li = document.createElement("li");
    this.setStatus(li, status, text);
    const list = $("cmd-log");
    list.prepend(li);
    while (list.children.length > LOG_MAX) {
      const oldest = list.lastElementChild;
      for (const [id, line] of this.items) if (line === oldest) this.items.delete(id);
      oldest.remove();
    }
    return li;
  }

  // Another run on this page: the old run's lines and what was known of its commands go — the new run
  // numbers its commands from 1 again, and its command 3's statuses once updated the old run's line #3.
  newRun() {
    this.items.clear();
    this.latest.clear();
    $("cmd-log").replaceChildren();
  }

  reset(button) {
    clearTimeout(button._timer);
    if (button.classList.contains("confirming")) {
      button.classList.remove("confirming");
      button.textContent = button.dataset.label;
    }
  }

  async send(body) {
    const li = this.log("sending", describe(body));
    li.dataset.command = body.command;
    try {
      const answer = await fetch("/api/command", {
        method: "POST",
        headers: { "Content-Type": "application/json", "Authorization": `token ${this.token}` },
        body: JSON.stringify(body),
      });
      const reply = await answer.json();
      if (!answer.ok) { this.setStatus(li, "error", `${describe(body)}: ${reply.error || answer.status}`); return; }
      li.dataset.id = String(reply.id);
      if (!li.isConnected) return;  // its line went (LOG_MAX, another run) while the POST was answered
      this.items.set(reply.id, li);
      this.setStatus(li, "queued", `#${reply.id} ${describe(body)}`);
      const known = this.latest.get(reply.id);
      if (known) this.onEvent(known);
    } catch (err) {  // the host went away between the click and the answer
      this.setStatus(li, "error", `${describe(body)}: not sent, the host does not answer (${err.message || err})`);
    }
  }

  setStatus(li, status, text) {
    li.dataset.status = status;
    li.textContent = `${text} — ${status}`;
  }

  // A "command" event of the run: update that command's line. Only the ground station's own records
  // (origin "gcs", whose ids its server gave): every sender numbers its commands from 1, and a fault
  // campaign's or a script's command 1 once took over the line of this page's command 1, its status too.
  onEvent(e) {
    if (e.kind !== "command" || e.origin !== GCS_ORIGIN || e.id === null || e.id === undefined) return;
    this.latest.delete(e.id);  // set again: the newest last (the oldest are forgotten first)
    this.latest.set(e.id, e);
    if (this.latest.size > LATEST_MAX) this.latest.delete(this.latest.keys().next().value);
    const li = this.items.get(e.id);
    if (!li) return;
    const detail = e.reason ? ` (${shortText(e.reason)})` : e.after_ms !== undefined ? ` after ${Number(e.after_ms).toFixed(0)} ms` : "";
    this.setStatus(li, e.status, `#${e.id} ${shortText(e.command)}${detail}`);
  }
}

function describe(body) {
  if (body.command !== "slew") return body.command;
  const deg = (x) => (x === null ? "?" : `${x}°`);
  return `slew to roll ${deg(body.roll_deg)}, pitch ${deg(body.pitch_deg)}, yaw ${deg(body.yaw_deg)}`;
}
