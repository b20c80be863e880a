// Side panel: live figures and per-node timing bars from GET /api/stats (polled ~2×/s), the
// viewer's own input → display latency (shown as it is measured), how frames come (tiles or a
// video stream, with its bitrate), and the balancer selector backed by GET/PUT /api/balancer (a
// watch page shows the balancer's name, no selector). The frame and size figures are the picture's.

import { nodeColor } from "./overlay.js";

export const PHASES = ["render", "readback", "encode", "send"];
const POLL_MS = 500;
/** What each phase of a node's bar is, shown on hover. */
export const PHASE_MEANING = {
  render: "drawing its tiles with OpenGL",
  readback: "copying the pixels from the GPU",
  encode: "compressing the tiles (JPEG, PNG)",
  send: "sending them to the coordinator",
};

/** Smallest 1, 2 or 5 × 10^k that is ≥ `ms` (the timing bars' full-scale value, ms). */
export function niceScale(ms) {
  if (!(ms > 0)) return 1;
  const power = 10 ** Math.floor(Math.log10(ms));
  return [1, 2, 5, 10].map((m) => m * power).find((step) => step >= ms * (1 - 1e-9));
}

/** Percent widths of a node's stacked phase segments on a `scaleMs` full-scale bar. */
export function segmentWidths(node, scaleMs) {
  return PHASES.map((phase) => Math.max(0, (100 * (Number(node[`${phase}_ms`]) || 0)) / scaleMs));
}

function el(tag, className, text) {
  const element = document.createElement(tag);
  if (className) element.className = className;
  if (text !== undefined) element.textContent = text;
  return element;
}

const fixed = (value, digits) => (Number.isFinite(value) ? value.toFixed(digits) : "–");

/** True when nothing is being rendered: no frame published in the last 2 s (fps 0) and none in
 * flight. Frames are rendered on demand, so a still camera and scene leave the cluster at rest. */
export function atRest(stats) {
  return !(Number(stats.fps) > 0) && !(Number(stats.frames_in_flight) > 0);
}

/** The fps figure: frames per second while frames come, "at rest" when none are needed. */
export function fpsText(stats) {
  return atRest(stats) ? "at rest" : fixed(Number(stats.fps), 1);
}

/** The detail figure: a point cloud's moving frames' budget from the stats' `point_budget` ("≤ 300k
 * points"), else the levels-of-detail bound from `lod_error_px` ("≤ 0.5 px"), or "full" (every triangle drawn). */
export function detailText(stats) {
  const points = Number(stats.point_budget);
  if (stats.point_budget != null && Number.isFinite(points)) {
    const count = points >= 1e6 ? `${fixed(points / 1e6, 2)}M` : `${Math.round(points / 1e3)}k`;
    return `≤ ${count} points`;
  }
  const bound = Number(stats.lod_error_px);
  return stats.lod_error_px != null && Number.isFinite(bound) ? `≤ ${fixed(bound, 2)} px` : "full";
}

/** The loading line from the stats' `loading` ({fraction, message, nodes_ready, nodes}), "" when none loads. */
export function loadingText(loading) {
  if (!loading) return "";
  const percent = Math.round(100 * (Number(loading.fraction) || 0));
  return `loading ${percent} %: ${loading.message ?? ""} (${loading.nodes_ready ?? 0} of ${loading.nodes ?? 0} nodes ready)`;
}

/** The still figure from the stats' `still_samples` ({done, estimated_psnr_db, …}): "16 samples · ≈49.3 dB"
 * when the picture shown holds samples, "–" for an interactive frame. */
export function stillText(stats) {
  const still = stats.still_samples ?? {};
  if (!(Number(still.done) > 0)) return "–";
  const estimate = Number.isFinite(still.estimated_psnr_db) ? ` · ≈${fixed(still.estimated_psnr_db, 1)} dB` : "";
  return `${still.done} sample${still.done === 1 ? "" : "s"}${stats.still ? "" : " (refining)"}${estimate}`;
}

/** What a node line's figures mean, shown on hover. */
export function nodeDetailTitle(node) {
  const name = node.name ?? `node ${node.id}`;
  if (node.state && node.state !== "ready") {
    return `${name} is ${node.state}: it draws no tiles until its scene is loaded`;
  }
  const tiles = Array.isArray(node.tiles) ? node.tiles.length : 0;
  const spread = Number.isFinite(node.calibration_spread) ? ` (±${Math.round(node.calibration_spread * 100)} %)` : "";
  const speed = node.speed_distinct
    ? `×${fixed(node.speed, 2)}: its speed measured at start-up${spread}, relative to the slowest node (×1.00); ` +
      "the balancer gives faster nodes more of the screen"
    : `its speed measured at start-up${spread} is the others' within what the measurements spread: no factor is ` +
      "shown, and the balancer starts every node with the same share";
  return [
    `${fixed(node.busy_ms, 1)} ms: ${name}'s time for its part of the last frame (render + readback + encode + send)`,
    `${tiles} tile${tiles === 1 ? "" : "s"}: the screen rectangles it drew in that frame`,
    speed,
  ].join("\n");
}

/** One line about a node: busy time, tile count and, where the nodes' speeds differ beyond their
 * measurements' spread, its relative speed; or its state while not ready. */
export function nodeDetail(node) {
  if (node.state && node.state !== "ready") {
    const progress = Number.isFinite(node.scene_progress) ? ` ${Math.round(node.scene_progress * 100)}%` : "";
    return `${node.state}${progress}`;
  }
  const tiles = Array.isArray(node.tiles) ? node.tiles.length : 0;
  const speed = node.speed_distinct ? ` · ×${fixed(node.speed, 2)}` : "";
  return `${fixed(node.busy_ms, 1)} ms · ${tiles} tile${tiles === 1 ? "" : "s"}${speed}`;
}

/** The viewer's input → display latency: p50 in ms and in frame intervals ("48 ms · 1.3 fr"),
 * just ms while no frame interval is known, "–" without samples. */
export function inputLatencyText(latency) {
  if (!latency || !latency.samples) return "–";
  const ms = `${fixed(latency.p50_ms, 0)} ms`;
  return latency.interval_ms > 0 ? `${ms} · ${fixed(latency.p50_ms / latency.interval_ms, 1)} fr` : ms;
}

/** The transport figure: "tiles", or the codec with the stream's target when known
 * ("h264 · 2.5 Mbit/s · 60 fps"); "–" before the coordinator said. */
export function transportText(transport, bitrate) {
  if (!transport) return "–";
  if (transport === "tiles" || !bitrate) return transport;
  return `${transport} · ${fixed(bitrate.bitrate / 1e6, 1)} Mbit/s · ${fixed(bitrate.max_fps, 0)} fps`;
}

const INPUT_LATENCY_TITLE = "Median time from a camera input in this browser to the frame showing it on screen: " +
  "in ms and in frame intervals (fr, 1 fr = the time between two frames)";

export class Panel {
  /**
   * @param {Document} doc  holds the panel's elements (ids in index.html)
   * @param {(path: string, init?: object) => Promise<Response>} api  fetch of the session's routes
   * @param {(nodes: object[]) => void} onNodes  receives each stats poll's node list (each with
   *   its `slot`, the node number in frame tiles)
   * @param {{messages: import("./messages.js").Messages, steering: boolean,
   *   onStats?: (stats: object) => void, onMissing?: () => void}} options  where messages go; whether
   *   this page may change the session (a watch page may not); each poll's stats; the session is gone
   */
  constructor(doc, api, onNodes, { messages, steering, onStats = () => {}, onMissing = () => {} }) {
    this.api = api;
    this.onNodes = onNodes;
    this.messages = messages;
    this.steering = steering;
    this.onStats = onStats;
    this.onMissing = onMissing;
    this.stopped = false;
    /** The frame on the picture ({frameId, width, height}), null before one is drawn. */
    this.picture = null;
    this.figure = (name) => doc.getElementById(`fig-${name}`);
    this.nodes = doc.getElementById("nodes");
    this.scale = doc.getElementById("bar-scale");
    this.renderState = doc.getElementById("render-state");
    this.loadingState = doc.getElementById("loading-state");
    for (const phase of PHASES) {
      doc.querySelector(`.legend .seg.${phase}`).parentElement.title = `${phase}: ${PHASE_MEANING[phase]}`;
    }
    this.select = doc.getElementById("balancer");
    this.params = doc.getElementById("balancer-params");
    this.balancerName = doc.getElementById("balancer-name");
    this.balancer = null;
    if (steering) this.select.addEventListener("change", () => this.chooseBalancer(this.select.value));
  }

  start() {
    this.loadBalancer();
    this.poll();
  }

  async poll() {
    if (this.stopped) return;
    try {
      const response = await this.api("api/stats");
      if (response.status === 404) {
        this.stop();
        this.onMissing();
        return;
      }
      if (!response.ok) throw new Error(`stats: HTTP ${response.status}`);
      this.showStats(await response.json());
      this.messages.status("");
    } catch (error) {
      this.messages.status(`stats unavailable (${error.message})`);
    }
    setTimeout(() => this.poll(), POLL_MS);
  }

  /** No more polls (the session is gone). */
  stop() {
    this.stopped = true;
  }

  /** The frame on the picture: the frame and size figures show it. */
  showPicture(frameId, width, height) {
    this.picture = { frameId, width, height };
    this.figure("frame").textContent = String(frameId);
    this.figure("size").textContent = `${width}×${height}`;
  }

  /** Show the viewer's input → display latency ({p50_ms, p90_ms, samples, interval_ms} or null). */
  showInputLatency(latency) {
    const figure = this.figure("input-latency");
    figure.textContent = inputLatencyText(latency);
    const p90 = latency ? `\np90 ${fixed(latency.p90_ms, 0)} ms over ${latency.samples} inputs` : "";
    figure.title = `${INPUT_LATENCY_TITLE}${p90}`;
  }

  /** Show how frames come: `stream` ({transport, codec, reason}, the coordinator's `stream`
   * message) and the stream's target `bitrate` ({bitrate, max_fps}, its `bitrate` message, or null). */
  showTransport(stream, bitrate) {
    const figure = this.figure("transport");
    figure.textContent = transportText(stream?.transport, bitrate);
    figure.dataset.transport = stream?.transport ?? "";
    figure.title = [stream?.codec && `codec ${stream.codec}`, stream?.reason].filter(Boolean).join("\n");
  }

  showStats(stats) {
    const rest = atRest(stats);
    this.figure("fps").textContent = fpsText(stats);
    this.figure("fps").dataset.rest = String(rest);
    this.renderState.hidden = !rest;
    this.figure("imbalance").textContent = fixed(stats.imbalance, 2);
    this.figure("imbalance-avg").textContent = fixed(stats.imbalance_avg, 2);
    this.figure("latency").textContent = fixed(stats.latency_ms, 0);
    if (this.picture === null) {   // once a frame is drawn, the figures are the picture's
      this.figure("frame").textContent = String(stats.frame ?? "–");
      this.figure("size").textContent = Array.isArray(stats.size) ? stats.size.join("×") : "–";
    }
    this.figure("still").textContent = stillText(stats);
    this.figure("detail").textContent = detailText(stats);
    this.loadingState.textContent = loadingText(stats.loading);
    this.loadingState.hidden = !stats.loading;
    this.showNodes(stats.nodes || []);
    this.onNodes(stats.nodes || []);
    this.onStats(stats);
    if (stats.balancer && stats.balancer !== this.balancer) this.loadBalancer();
  }

  showNodes(nodes) {
    const busiest = Math.max(0, ...nodes.map((n) => PHASES.reduce((sum, p) => sum + (Number(n[`${p}_ms`]) || 0), 0)));
    const scaleMs = niceScale(busiest);
    this.scale.textContent = `${scaleMs} ms`;
    while (this.nodes.children.length > nodes.length) this.nodes.lastElementChild.remove();
    while (this.nodes.children.length < nodes.length) this.nodes.append(this.nodeRow());
    nodes.forEach((node, index) => {
      const row = this.nodes.children[index];
      row.querySelector(".swatch").style.background = nodeColor(node.slot);
      row.querySelector(".name").textContent = node.name ?? `node ${node.id}`;
      const detail = row.querySelector(".detail");
      detail.textContent = nodeDetail(node);
      detail.title = nodeDetailTitle(node);
      const widths = segmentWidths(node, scaleMs);
      row.querySelectorAll(".seg").forEach((segment, i) => {
        segment.style.width = `${widths[i]}%`;
        segment.title = `${PHASES[i]} ${fixed(Number(node[`${PHASES[i]}_ms`]), 2)} ms: ${PHASE_MEANING[PHASES[i]]}`;
      });
    });
  }

  nodeRow() {
    const row = el("li", "node");
    const head = el("div", "node-head");
    head.append(el("span", "swatch"), el("span", "name"), el("span", "detail"));
    const bar = el("div", "bar");
    for (const phase of PHASES) bar.append(el("span", `seg ${phase}`));
    row.append(head, bar);
    return row;
  }

  async loadBalancer() {
    try {
      const response = await this.api("api/balancer");
      if (!response.ok) throw new Error(`balancer: HTTP ${response.status}`);
      this.showBalancer(await response.json());
    } catch (error) {
      this.messages.status(`balancer unavailable (${error.message})`);
    }
  }

  /** Fill the selector from {name, available} and show `params` when given. */
  showBalancer({ name, params, available }) {
    this.balancer = name;
    this.balancerName.textContent = name;
    const names = available && available.length ? available : [name];
    if ([...this.select.options].map((o) => o.value).join() !== names.join()) {
      this.select.replaceChildren(...names.map((n) => new Option(n, n)));
    }
    if (document.activeElement !== this.select) this.select.value = name;
    if (params === undefined) return;
    const entries = Object.entries(params);
    this.params.textContent = entries.length ? entries.map(([k, v]) => `${k} = ${JSON.stringify(v)}`).join("\n") : "no parameters";
  }

  async chooseBalancer(name) {
    this.messages.clear();
    try {
      const response = await this.api("api/balancer", {
        method: "PUT",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ name, params: {} }),
      });
      if (!response.ok) throw new Error(`${response.status} ${(await response.text()).slice(0, 200)}`);
    } catch (error) {
      this.messages.say(`could not switch balancer: ${error.message}`);
    }
    this.select.blur();
    await this.loadBalancer();
  }
}
