// What users do with the model on screen (issue 35): a click (or a tap) picks what the pixel shows
// (GET …/pick), and the tool in use does something with it — select (the nodes tint the object in
// every tile: PUT …/selection; its name and properties in the panel), measure a distance between
// two points or the angle between three (drawn over the picture, nothing re-rendered), pin a note
// (PUT …/annotations, kept with the session), or cut the model by the plane through the point,
// facing the eye (PUT …/clip). The section box cuts to a box set with sliders. Esc clears the
// selection and the measurement. Posters and films are started here, and their progress shown.

import { angle, boxFrom, distance, formatLength, framePixel, isClick, project, unitsOf, withCut } from "./measure.js";
import { fitFrame } from "./overlay.js";

/** What the hint says for each tool. */
const HINTS = {
  select: "click the picture to select an object · Esc clears",
  distance: "click two points to measure their distance",
  angle: "click three points: the angle is at the second",
  note: "click a point to pin the note's text to it",
  cut: "click a surface to cut away what is in front of it",
};
/** How often the notes are read again (another viewer may have changed them), ms. */
export const NOTES_MS = 3000;
/** The section box's sliders: their steps over the scene's bounds. */
const BOX_STEPS = 1000;
const MARK_COLOR = "#ffd166";

export class Tools {
  /**
   * @param {Document} doc  holds the tools section's elements (#tools, #tool-hint, …) and #marks
   * @param {{frame: HTMLCanvasElement, api: (path: string, init?: object) => Promise<Response>,
   *   steering: boolean, messages: {say: (text: string) => void, clear: () => void},
   *   view: () => {camera: object|null, size: number[]|null, bounds: number[][]|null},
   *   link: (path: string) => string}} options
   *   link: the address of a session API path (`api/posters/ID.png`) for a download link
   */
  constructor(doc, { frame, api, steering, messages, view, link }) {
    this.doc = doc;
    this.frame = frame;
    this.marks = doc.getElementById("marks");
    this.api = api;
    this.steering = steering;
    this.messages = messages;
    this.view = view;
    this.link = link;
    this.tool = "select";
    this.points = [];
    this.measurement = null;
    this.notes = [];
    this.selection = null;
    this.scene = "";
    this.clip = null;
    this.jobs = [];
    this.down = null;
    this.drawn = false;
    const $ = (id) => doc.getElementById(id);
    this.$ = $;
    frame.addEventListener("pointerdown", (event) => {
      if (event.isPrimary) this.down = { x: event.clientX, y: event.clientY, t: performance.now() };
    });
    frame.addEventListener("pointerup", (event) => {
      const down = this.down;
      this.down = null;
      if (down && event.isPrimary && event.button === 0 && isClick(down, { x: event.clientX, y: event.clientY,
        t: performance.now() })) this.click(event);
    });
    for (const button of doc.querySelectorAll("[data-tool]")) {
      button.addEventListener("click", () => this.use(button.dataset.tool));
    }
    $("clear-cuts").addEventListener("click", () => this.setClip({}));
    $("box-on").addEventListener("change", () => this.boxChanged());
    for (const input of doc.querySelectorAll("#section-box input[type=range]")) {
      input.addEventListener("input", () => this.boxChanged());
    }
    $("make-poster").addEventListener("click", () => this.startJob("posters"));
    $("make-film").addEventListener("click", () => this.startJob("recordings"));
    new ResizeObserver(() => this.redraw()).observe(this.marks);
  }

  /** Read the session's clip, selection and notes, and keep the notes fresh. */
  async start() {
    await Promise.all([this.loadClip(), this.loadNotes()]);
    try {
      const selected = await (await this.api("api/selection")).json();
      this.selection = selected.object ? { object: selected.object } : null;
      this.showSelection();
    } catch (error) {
      console.warn("tessera: selection:", error);
    }
    if (!this.stopped) this.notesTimer = setInterval(() => this.loadNotes(), NOTES_MS);
  }

  /** Stop asking for the notes (the session is gone). */
  stop() {
    this.stopped = true;
    clearInterval(this.notesTimer);
  }

  /** Use tool `tool` (select, distance, angle, note, cut): the points picked so far are dropped. */
  use(tool) {
    this.tool = tool;
    this.points = [];
    for (const button of this.doc.querySelectorAll("[data-tool]")) {
      button.setAttribute("aria-pressed", String(button.dataset.tool === tool));
    }
    this.$("tool-hint").textContent = HINTS[tool];
    this.redraw();
  }

  /** Esc: no selection, no measurement, no points picked. */
  clear() {
    this.points = [];
    this.measurement = null;
    this.$("measure-result").hidden = true;
    if (this.selection && this.steering) this.put("api/selection", { object: null });
    this.selection = null;
    this.showSelection();
    this.redraw();
  }

  async click(event) {
    const { size } = this.view();
    if (!size) return;
    const rect = this.frame.getBoundingClientRect();
    const pixel = framePixel(event.clientX - rect.left, event.clientY - rect.top, rect.width, rect.height, ...size);
    if (!pixel) return;
    this.messages.clear();
    let hit;
    try {
      const response = await this.api(`api/pick?x=${pixel[0]}&y=${pixel[1]}`);
      hit = await response.json();
      if (!response.ok) throw new Error(hit.detail ?? response.statusText);
    } catch (error) {
      this.messages.say(`pick failed: ${error.message}`);
      return;
    }
    this.picked(hit);
  }

  /** What the tool in use does with a pick's answer. */
  async picked(hit) {
    if (this.tool === "select") {
      this.selection = hit.hit ? hit : null;
      if (this.steering) await this.put("api/selection", { object: hit.hit ? hit.object : null });
      await this.showSelection();
      return;
    }
    if (!hit.hit) return;
    if (this.tool === "note") {
      const text = this.$("note-text").value.trim() || `note ${this.notes.length + 1}`;
      await this.saveNotes([...this.notes, { point: hit.point, text }]);
    } else if (this.tool === "cut") {
      await this.setClip(withCut(this.clip, hit.point, hit.normal));
    } else {
      this.points.push(hit.point);
      const wanted = this.tool === "distance" ? 2 : 3;
      if (this.points.length === wanted) {
        const [a, b, c] = this.points;
        this.measurement = this.tool === "distance" ? { kind: "distance", points: [a, b], value: distance(a, b) }
          : { kind: "angle", points: [a, b, c], value: angle(a, b, c) };
        this.points = [];
        this.showMeasurement();
      }
    }
    this.redraw();
  }

  showMeasurement() {
    const result = this.$("measure-result");
    const m = this.measurement;
    result.hidden = !m;
    if (m) result.textContent = m.kind === "distance" ? `distance ${formatLength(m.value, unitsOf(this.scene))}`
      : `angle ${m.value.toFixed(1)}°`;
  }

  /** The selected object's name and properties (GET …/objects) with what the pick said. */
  async showSelection() {
    const box = this.$("selection");
    const hit = this.selection;
    box.hidden = !hit;
    this.redraw();
    if (!hit) return;
    this.$("selection-name").textContent = hit.object;
    const lines = [];
    if (hit.point) {
      const units = unitsOf(this.scene);
      lines.push(`point ${hit.point.map((v) => v.toFixed(3)).join(", ")} (${units})`);
      lines.push(`normal ${hit.normal.map((v) => v.toFixed(3)).join(", ")}`);
      lines.push(`depth ${formatLength(hit.depth, units)} · triangle ${hit.primitive}`);
    }
    try {
      const objects = await (await this.api("api/objects")).json();
      const object = Array.isArray(objects) ? objects.find((o) => o.name === hit.object) : null;
      if (object) {
        lines.push(`${object.triangles} triangles${object.parent ? ` · in ${object.parent}` : ""}`);
        lines.push(`at ${object.translation.map((v) => v.toFixed(3)).join(", ")}`);
      }
    } catch (error) {
      console.warn("tessera: objects:", error);
    }
    this.$("selection-props").textContent = lines.join("\n");
  }

  async put(path, body) {
    const response = await this.api(path, { method: "PUT", headers: { "content-type": "application/json" },
      body: JSON.stringify(body) });
    if (!response.ok) {
      const detail = await response.json().catch(() => ({}));
      this.messages.say(`${path.replace("api/", "")}: ${detail.detail ?? response.statusText}`);
      return null;
    }
    return response.json();
  }

  async loadClip() {
    try {
      this.clip = await (await this.api("api/clip")).json();
    } catch (error) {
      console.warn("tessera: clip:", error);
    }
  }

  async setClip(clip) {
    if ((await this.put("api/clip", clip)) !== null) {
      this.clip = { planes: [], box: null, ...clip };
      this.$("cuts").textContent = this.describeClip();
    }
  }

  describeClip() {
    const planes = this.clip?.planes?.length ?? 0;
    const parts = [planes ? `${planes} cut${planes > 1 ? "s" : ""}` : "", this.clip?.box ? "section box" : ""];
    return parts.filter(Boolean).join(" · ") || "nothing cut";
  }

  /** The section box's sliders moved (or it was turned on or off): cut to it. */
  boxChanged() {
    clearTimeout(this.boxTimer);
    this.boxTimer = setTimeout(() => {
      const { bounds } = this.view();
      if (!bounds) return;
      const value = (id) => Number(this.$(id).value) / BOX_STEPS;
      const box = this.$("box-on").checked ? boxFrom(bounds, {
        min: [value("box-x0"), value("box-y0"), value("box-z0")], max: [value("box-x1"), value("box-y1"), value("box-z1")],
      }) : null;
      this.setClip({ ...(this.clip ?? {}), box });
    }, 120);
  }

  async loadNotes() {
    try {
      const notes = await (await this.api("api/annotations")).json();
      if (Array.isArray(notes)) {
        this.notes = notes;
        this.redraw();
      }
    } catch (error) {
      console.warn("tessera: annotations:", error);
    }
  }

  async saveNotes(notes) {
    const saved = await this.put("api/annotations", notes);
    if (saved !== null) this.notes = saved;
  }

  async startJob(kind) {
    const { size } = this.view();
    if (!size) return;
    const even = (v) => Math.max(16, v - (v % 2));
    const body = kind === "posters" ? { size: size.map((v) => Math.min(16384, 4 * v)) }
      : { orbit: { turns: 1, seconds: 10 }, fps: 30, size: size.map(even) };
    const response = await this.api(`api/${kind}`, { method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify(body) });
    const answer = await response.json().catch(() => ({}));
    if (!response.ok) this.messages.say(`${kind}: ${answer.detail ?? response.statusText}`);
  }

  /** The panel's stats came (`/api/stats`): the scene's name and the session's jobs. */
  showStats(stats) {
    this.scene = stats.scene ?? this.scene;
    this.showJobs(Array.isArray(stats.jobs) ? stats.jobs : []);
  }

  showJobs(jobs) {
    this.jobs = jobs;
    const list = this.$("jobs");
    list.replaceChildren(...jobs.map((job) => {
      const item = this.doc.createElement("li");
      const kind = job.kind === "poster" ? "poster" : "film";
      item.dataset.state = job.state;
      if (job.state === "done") {
        const link = this.doc.createElement("a");
        const file = kind === "poster" ? `posters/${job.id}.png` : `recordings/${job.id}.mp4`;
        link.href = this.link(`api/${file}`);
        link.textContent = `${kind} ready`;
        link.download = "";
        item.append(link);
      } else {
        const progress = job.total ? ` ${job.done}/${job.total}` : "";
        item.textContent = `${kind} ${job.state}${progress}${job.reason ? `: ${job.reason}` : ""}`;
      }
      return item;
    }));
  }

  /** Draw the picked points, the measurement and the notes over the picture, where the camera shows them. */
  redraw() {
    const canvas = this.marks;
    const marked = Boolean(this.measurement || this.points.length || this.notes.length);
    if (!marked && !this.drawn) return;   // nothing to draw and nothing drawn: no canvas work a frame
    this.drawn = marked;
    const ratio = window.devicePixelRatio || 1;
    const [boxW, boxH] = [canvas.clientWidth, canvas.clientHeight];
    canvas.width = Math.round(boxW * ratio);
    canvas.height = Math.round(boxH * ratio);
    const { camera, size } = this.view();
    if (!camera || !size) return;
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    const fit = fitFrame(size[0], size[1], boxW, boxH);
    const screen = (point) => {
      const at = project(camera, size[0], size[1], point);
      return at && [fit.x + at[0] * fit.scale, fit.y + at[1] * fit.scale];
    };
    ctx.font = "600 12px system-ui, sans-serif";
    ctx.lineWidth = 2;
    ctx.strokeStyle = MARK_COLOR;
    ctx.fillStyle = MARK_COLOR;
    const dot = (at) => {
      ctx.beginPath();
      ctx.arc(at[0], at[1], 4, 0, 2 * Math.PI);
      ctx.fill();
    };
    const label = (at, text) => {
      const width = ctx.measureText(text).width;
      ctx.fillStyle = "rgb(20 23 29 / 0.85)";
      ctx.fillRect(at[0] + 8, at[1] - 18, width + 10, 18);
      ctx.fillStyle = MARK_COLOR;
      ctx.fillText(text, at[0] + 13, at[1] - 5);
    };
    const m = this.measurement;
    if (m) {
      const ats = m.points.map(screen);
      if (ats.every(Boolean)) {
        ctx.beginPath();
        ats.forEach((at, i) => (i ? ctx.lineTo(...at) : ctx.moveTo(...at)));
        ctx.stroke();
        ats.forEach(dot);
        const where = m.kind === "distance" ? [(ats[0][0] + ats[1][0]) / 2, (ats[0][1] + ats[1][1]) / 2] : ats[1];
        label(where, m.kind === "distance" ? formatLength(m.value, unitsOf(this.scene)) : `${m.value.toFixed(1)}°`);
      }
    }
    for (const point of this.points) {
      const at = screen(point);
      if (at) dot(at);
    }
    for (const note of this.notes) {
      const at = screen(note.point);
      if (!at) continue;
      dot(at);
      label(at, note.text);
    }
  }
}
