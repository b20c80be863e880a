// The notebook view of a session (issue 33): an anywidget front end built from the viewer's own
// modules (web/: TFRM parsing, the compositor, the orbit controls, the latency tracker, the frame
// size rule). Frames and input travel through the kernel's comm by default: binary TFRM messages
// as buffers, each acknowledged once drawn so the kernel sends the next (jupyter_rfb's throttle);
// with transport "direct" the page opens the coordinator's viewer socket itself.
// Through the comm every message from the page is a kernel request (the kernel relays it, and
// Jupyter's server carries it and the kernel's idle back): the comm view sends at most
// COMM_INPUT_WINDOW.inFlight cameras not yet answered by a frame, the newest camera waiting
// meanwhile, and what the page sends while taking a frame rides with that frame's acknowledgement:
// about one message a frame. The kernel publishes no busy for these messages
// (tessera/client/kernel_status.py): JupyterLab restyled its kernel indicators, the tab's icon and
// title at every busy and idle, twice a frame, on the CPU the render nodes draw with.

import { Compositor } from "./compositor.js";
import { Connection } from "./connection.js";
import { Controls } from "./controls.js";
import { CameraInput, LatencyTracker } from "./latency.js";
import { frameBounds, minDistanceFor } from "./orbit.js";
import { fitFrame } from "./overlay.js";
import { parseFrame } from "./protocol.js";
import { frameSizeFor } from "./session.js";

/** How long the cell must rest before the view asks for frames of its new size (ms). */
const RESIZE_DEBOUNCE_MS = 300;
/** How often the stats line is refreshed (ms). */
const STATS_MS = 500;
/** Camera inputs in flight through the comm, at most (the coordinator works on two frames of a
 * session at once), and how long one may go unanswered before it no longer counts (ms). */
const COMM_INPUT_WINDOW = { inFlight: 2, timeoutMs: 1000 };

function element(tag, className, parent) {
  const node = document.createElement(tag);
  node.className = className;
  parent.appendChild(node);
  return node;
}

function render({ model, el }) {
  const box = element("div", "tessera-view", el);
  const canvas = element("canvas", "tessera-frame", box);
  const badge = element("span", "tessera-badge", box);
  const line = element("div", "tessera-stats", el);
  canvas.tabIndex = 0;
  const state = { camera: null, bounds: null, frameId: null, framesDrawn: 0, still: false, samples: 0,
    stillSamples: null, inputLatency: null, size: null, error: "", transport: model.get("transport"),
    drawnAt: [], frameHops: [], relayWaits: [], inputHopMs: null };
  // Read-only state for tests and the console, as the viewer page's window.tessera.
  el.tesseraView = state;

  const place = () => {
    box.style.width = `${model.get("width")}px`;
    box.style.height = `${model.get("height")}px`;
  };
  place();
  model.on("change:width", place);
  model.on("change:height", place);

  const tracker = new LatencyTracker();
  let transport = null;
  const send = (message) => transport !== null && transport.send(message);

  function painted(frame) {
    state.frameId = frame.frameId;
    state.framesDrawn += 1;
    state.still = frame.still;
    state.samples = frame.samples ?? 0;
    state.size = [frame.width, frame.height];
    const now = performance.now();
    state.drawnAt.push(now);
    if (state.drawnAt.length > 30) state.drawnAt.shift();
    if (tracker.drawn(frame.inputSeq, now) !== null) state.inputLatency = tracker.summary();
    badge.textContent = frame.still ? "still" : state.samples > 0 ? `refining ${state.samples}/${state.stillSamples ?? "?"}`
      : "interactive";
    badge.dataset.quality = frame.still ? "still" : state.samples > 0 ? "refining" : "interactive";
  }
  const compositor = new Compositor(canvas, painted, (error) => console.warn("tessera: frame dropped:", error));

  const cameraInput = new CameraInput(send, tracker, (callback) => requestAnimationFrame(callback),
    () => performance.now(), state.transport === "direct" ? null : COMM_INPUT_WINDOW);
  function setCamera(camera) {
    state.camera = camera;
    cameraInput.set(camera);
  }
  const viewHeight = () => {
    const [w, h] = [canvas.width || 1, canvas.height || 1];
    return Math.max(1, fitFrame(w, h, canvas.clientWidth, canvas.clientHeight).scale * h);
  };
  const controls = new Controls(canvas, { camera: () => state.camera, setCamera, viewHeight,
    minDistance: () => minDistanceFor(state.bounds) });
  const adoptCamera = (camera) => {
    if (camera && !controls.interacting && !cameraInput.pending) state.camera = camera;
  };
  canvas.addEventListener("dblclick", () => state.bounds && setCamera(frameBounds(state.bounds, state.camera?.fovy_deg ?? 45)));

  let sizeSent = null;
  function sendSize() {
    const size = frameSizeFor(box.clientWidth, box.clientHeight, window.devicePixelRatio);
    if (!size || (sizeSent && size[0] === sizeSent[0] && size[1] === sizeSent[1])) return;
    if (send({ type: "size", size })) sizeSent = size;
  }
  let sizeTimer = null;
  const resized = new ResizeObserver(() => {
    clearTimeout(sizeTimer);
    sizeTimer = setTimeout(sendSize, RESIZE_DEBOUNCE_MS);
  });
  resized.observe(box);

  function onText(message) {
    if (message.type === "hello") {
      sizeSent = null;
      state.bounds = message.bounds;
      state.stillSamples = message.still_samples ?? null;
      adoptCamera(message.camera);
      setTimeout(sendSize, 0);
    } else if (message.type === "camera") {
      adoptCamera(message.camera);
    } else if (message.type === "scene") {
      state.bounds = message.bounds;
      adoptCamera(message.camera);
    } else if (message.type === "error") {
      state.error = message.message;
    }
  }
  /** A frame came: drawn, its input answered; returns its id (null: not a frame). */
  function onBinary(buffer) {
    try {
      const frame = parseFrame(buffer);
      compositor.submit(frame);
      cameraInput.answered(frame.inputSeq);
      return frame.frameId;
    } catch (error) {
      console.warn("tessera: bad frame:", error);
      return null;
    }
  }

  let connection = null;
  if (state.transport === "direct") {
    connection = new Connection(model.get("direct_url"), { onText, onBinary,
      onState: ({ state: s, detail }) => { state.connection = detail ? `${s} · ${detail}` : s; } });
    transport = connection;
    connection.start();
  } else {
    // Messages sent while a frame is taken (the camera the window held): they go with its acknowledgement.
    let riding = null;
    transport = {
      send: (message) => {
        if (riding) riding.push(message);
        else model.send({ type: "viewer", message, sent_ms: Date.now() });
        return true;
      },
    };
    model.on("msg:custom", (message, buffers) => {
      if (message.type === "frame" && buffers.length) {
        // What the comm costs: the kernel → page hop of each frame, the page → kernel hop of input.
        state.frameHops.push(Date.now() - message.sent_ms);
        if (state.frameHops.length > 60) state.frameHops.shift();
        state.inputHopMs = message.input_hop_ms;
        state.relayWaits.push(message.waited_ms);
        if (state.relayWaits.length > 60) state.relayWaits.shift();
        const view = buffers[0];
        const buffer = view.buffer.slice(view.byteOffset, view.byteOffset + view.byteLength);
        // Acknowledged once handed to the compositor (or refused): the kernel then sends the newest
        // frame it holds, after passing on the messages riding with the acknowledgement.
        riding = [];
        const frameId = onBinary(buffer);
        const messages = riding;
        riding = null;
        model.send({ type: "ack", frame: frameId, messages, sent_ms: Date.now() });
      } else if (message.type === "control") {
        onText(message.message);
      } else if (message.type === "closed") {
        state.error = message.reason;
      }
    });
    model.send({ type: "ready" });
  }

  const reportEvery = setInterval(() => {
    const latency = state.inputLatency;
    if (latency) send({ type: "latency", ...latency });
  }, 1000);
  const statsEvery = setInterval(() => {
    const times = state.drawnAt;
    const fps = times.length > 1 && performance.now() - times[times.length - 1] < 1000
      ? (1000 * (times.length - 1)) / (times[times.length - 1] - times[0]) : 0;
    const parts = [state.transport, state.size ? `${state.size[0]}×${state.size[1]}` : "no frame yet"];
    if (state.frameId !== null) parts.push(`frame ${state.frameId}`, `${fps.toFixed(1)} fps`);
    if (state.inputLatency) parts.push(`input→frame ${state.inputLatency.p50_ms.toFixed(0)} ms`);
    if (state.error) parts.push(state.error);
    line.textContent = parts.join(" · ");
  }, STATS_MS);

  return () => {
    clearInterval(reportEvery);
    clearInterval(statsEvery);
    resized.disconnect();
    if (connection && connection.socket) {
      connection.start = () => {};   // no reconnect once the view is gone
      connection.socket.close();
    }
  };
}

export default { render };
