// Tessera viewer entry point: wires the WebSocket, the frame compositor (tiles), the video stream
// (WebCodecs), the overlay, the input controls, the input → display latency tracker and the stats
// panel together, and exposes read-only state as `window.tessera`.

import { AnimationControls } from "./animation.js";
import { Compositor } from "./compositor.js";
import { Connection } from "./connection.js";
import { Controls } from "./controls.js";
import { CameraInput, LatencyTracker } from "./latency.js";
import { Messages } from "./messages.js";
import { frameBounds, minDistanceFor } from "./orbit.js";
import { drawOverlay, fitFrame, ownershipTiles, readbackTiles } from "./overlay.js";
import { Panel } from "./panel.js";
import { parseFrame } from "./protocol.js";
import { apiInit, frameSizeFor, sessionApiPath, sessionFromQuery, steers, viewSocketPath } from "./session.js";
import { SessionControls } from "./session_controls.js";
import { Tools } from "./tools.js";
import { VideoStream, decodableCodecs } from "./video.js";
import { isVideo, parseVideo } from "./video_protocol.js";
import { ClockOffset, Presenter, drawCellOutlines } from "./wall.js";

// Opened with `?token=`, the page has set the token as a cookie (HttpOnly) that the viewer's sockets
// and API calls carry: take it out of the address bar (and so out of history and shared links).
if (new URLSearchParams(location.search).has("token")) {
  const clean = new URL(location.href);
  clean.searchParams.delete("token");
  history.replaceState(null, "", clean.href);
}
/** How often the viewer reports its input → display latency to the coordinator, while it changes (ms). */
const LATENCY_REPORT_MS = 1000;
/** How often a viewer on a video stream sends its `stream_report` (ms). */
const STREAM_REPORT_MS = 1000;

/** Address relative to the page (so a path prefix in front of the coordinator still works). */
function address(path, scheme) {
  const url = new URL(path, document.baseURI);
  if (scheme) url.protocol = scheme;
  return url.href;
}

/** The session this page shows (`?session=…[&watch=1]`; none: the default session). */
const session = sessionFromQuery(location.search);
/** This page may change its session (a watch link and a wall's cell may not: they show no such control). */
const steering = steers(session);
document.body.dataset.watching = String(session.watching);
const api = (path, init) => fetch(address(sessionApiPath(path, session)), apiInit(init, session));
const messages = new Messages(document);

const state = {
  frameId: null,
  viewerId: null,
  still: false,
  // The samples of the progressive still on the canvas (0: an interactive frame), and how many the
  // coordinator accumulates (hello's still_samples).
  samples: 0,
  stillSamples: null,
  // The still stops when it converged (hello's still_adaptive): stillSamples is then the most it takes.
  stillAdaptive: false,
  inputLatency: null,
  camera: null,
  framesDrawn: 0,
  connected: false,
  size: null,
  bounds: null,
  overlay: false,
  // A display wall's session (issue 22): {wall: {cols, rows, cell, bezel}, cell: [col, row] | null}.
  wall: null,
  // How frames come (issue 21): "tiles" or the video codec the coordinator chose ("h264", …).
  transport: "tiles",
  // The video stream's target: {bitrate: bit/s, max_fps} (the coordinator's `bitrate`), or null.
  bitrate: null,
};
const lastTiles = { width: 0, height: 0, tiles: [] };

const $ = (id) => document.getElementById(id);
const frameCanvas = $("frame");
const overlayCanvas = $("overlay");

// Read-only view of the state for tests and the console: each read returns a copy.
Object.defineProperty(window, "tessera", {
  value: Object.freeze(Object.defineProperties({}, {
    ...Object.fromEntries(
      Object.keys(state).map((key) => [key, { get: () => structuredClone(state[key]), enumerable: true }]),
    ),
    framesDropped: { get: () => compositor.dropped, enumerable: true },
    videoFramesDecoded: { get: () => video.decoded, enumerable: true },
    videoFramesPainted: { get: () => video.painted, enumerable: true },
    videoFramesDropped: { get: () => video.dropped, enumerable: true },
    keyframeRequests: { get: () => video.keyframeRequests, enumerable: true },
    animation: { get: () => structuredClone(animation.state), enumerable: true },
  })),
});

const nodeNames = new Map();
let nodeReadback = [];

/** This page drives a wall and sees it whole: its cells are outlined. */
const wallDriver = () => state.wall !== null && state.wall.cell === null;

function redrawOverlay() {
  const tiles = state.overlay ? ownershipTiles(lastTiles.tiles, nodeReadback) : [];
  drawOverlay(overlayCanvas, lastTiles.width, lastTiles.height, tiles, (slot) => nodeNames.get(slot) ?? `node ${slot}`);
  if (wallDriver()) drawCellOutlines(overlayCanvas, lastTiles.width, lastTiles.height, state.wall.wall);
}

function setOverlay(on) {
  state.overlay = on;
  $("toggle-overlay").checked = on;
  redrawOverlay();
}

function setSize(width, height) {
  state.size = [width, height];
  if (frameCanvas.width !== width || frameCanvas.height !== height) {
    frameCanvas.width = width;
    frameCanvas.height = height;
  }
}

/** CSS pixel height of the image inside the letterboxed canvas element. */
function viewHeight() {
  const [w, h] = [frameCanvas.width, frameCanvas.height];
  return Math.max(1, fitFrame(w, h, frameCanvas.clientWidth, frameCanvas.clientHeight).scale * h);
}

const latencyTracker = new LatencyTracker();
const cameraInput = new CameraInput((message) => connection.send(message), latencyTracker,
  (callback) => requestAnimationFrame(callback), () => performance.now());
function setCamera(camera) {
  if (session.cell) return; // a wall's cell steers nothing
  state.camera = camera;
  cameraInput.set(camera);
}

/** Total latency samples last reported to the coordinator (reset when a coordinator says hello). */
let samplesReported = 0;
function reportLatency() {
  if (latencyTracker.total === samplesReported) return;
  if (connection.send({ type: "latency", ...state.inputLatency })) samplesReported = latencyTracker.total;
}

/** The badge: the converged still (with its samples), a progressive still refining (k of N
 * samples), or an interactive frame. */
function showQuality(frame) {
  const badge = $("quality-badge");
  const samples = frame.samples ?? 0;
  if (frame.still) {
    badge.dataset.quality = "still";
    badge.textContent = samples > 1 ? `still · ${samples} samples` : "still";
  } else if (samples > 0) {
    badge.dataset.quality = "refining";
    badge.textContent = state.stillAdaptive ? `refining · ${samples} samples`
      : `refining ${samples}/${state.stillSamples ?? "?"}`;
  } else {
    badge.dataset.quality = "interactive";
    badge.textContent = "interactive";
  }
  badge.hidden = false;
}

/** A frame is on the canvas: a TFRM frame of tiles, or a decoded video frame (no tiles, not still). */
function painted(frame) {
  shownId = frame.frameId;
  state.frameId = frame.frameId;
  state.framesDrawn += 1;
  state.still = frame.still;
  if (latencyTracker.drawn(frame.inputSeq, performance.now()) !== null) {
    state.inputLatency = latencyTracker.summary();
    panel.showInputLatency(state.inputLatency);
  }
  if (!state.size || state.size[0] !== frame.width || state.size[1] !== frame.height) {
    setSize(frame.width, frame.height);
  }
  lastTiles.width = frame.width;
  lastTiles.height = frame.height;
  lastTiles.tiles = frame.tiles.map(({ x, y, w, h, node }) => ({ x, y, w, h, node }));
  if (state.overlay || wallDriver()) redrawOverlay();
  $("frame-badge").textContent = `frame ${frame.frameId}`;
  panel.showPicture(frame.frameId, frame.width, frame.height);
  sessionControls.showPicture(frame.width, frame.height);
  tools.redraw();
  state.samples = frame.samples ?? 0;
  showQuality(frame);
}

/** With a video stream, frames come by two paths (video; still frames as tiles): only a frame newer
 * than the one on the canvas is painted. */
let shownId = null;
const newerThanShown = (frameId) => shownId === null || frameId > shownId;

const compositor = new Compositor(frameCanvas, painted, (error) => console.warn("tessera: frame dropped:", error));
compositor.drawable = (frame) => !video.active || newerThanShown(frame.frameId);

const video = new VideoStream(frameCanvas, {
  paintable: newerThanShown,
  onPainted: (frame) => painted({ ...frame, still: false, tiles: [] }),
  requestKeyframe: () => connection.send({ type: "keyframe" }),
  onError: (error) => console.warn("tessera: video frame lost:", error),
});

/** The coordinator's last `stream` message ({transport, codec, reason}), null before one came. */
let stream = null;

/** Offer the codecs this browser decodes at `width`×`height` (none: tiles), unless a newer hello came. */
let hellos = 0;
async function offerStream(width, height) {
  const hello = hellos;
  const codecs = await decodableCodecs(width, height);
  if (hello === hellos) connection.send({ type: "stream_offer", codecs });
}

function reportStream() {
  if (video.active) connection.send({ type: "stream_report", ...video.report(performance.now()) });
}

const controls = steering ? new Controls(frameCanvas, {
  camera: () => state.camera,
  setCamera,
  viewHeight,
  minDistance: () => minDistanceFor(state.bounds),
}) : null;

function adoptCamera(camera) {
  if (camera && !controls?.interacting && !cameraInput.pending) state.camera = camera;
}

function onText(message) {
  switch (message.type) {
    case "hello":
      sizeSent = null;
      if (session.key && !session.watching && !session.cell) setTimeout(sendSize, 0);
      state.viewerId = message.viewer;
      state.stillSamples = message.still_samples ?? null;
      state.stillAdaptive = message.still_adaptive === true;
      samplesReported = 0;
      shownId = null;
      hellos += 1;
      video.reset();
      state.transport = video.transport;
      state.bitrate = null;
      stream = null;
      panel.showTransport(null, null);
      if (!session.cell) offerStream(...message.size);
      setSize(...message.size);
      state.bounds = message.bounds;
      adoptCamera(message.camera);
      panel.showBalancer({ name: message.balancer, available: message.balancers });
      if (message.bounds) animation.load();
      break;
    case "camera":
      adoptCamera(message.camera);
      break;
    case "scene":
      state.bounds = message.bounds;
      adoptCamera(message.camera);
      animation.load();
      break;
    case "wall":
      state.wall = { wall: message.wall, cell: message.cell };
      if (message.cell) startCell();
      else redrawOverlay();
      break;
    case "present":
      presenter.present(message);
      break;
    case "stream":
      video.choose(message);
      stream = message;
      state.transport = video.transport;
      if (!video.active) state.bitrate = null;
      panel.showTransport(stream, state.bitrate);
      break;
    case "bitrate":
      state.bitrate = { bitrate: message.bitrate, max_fps: message.max_fps };
      panel.showTransport(stream, state.bitrate);
      break;
    case "pong":
      clock.sample(message.t0, performance.now(), message.clock_ms);
      break;
    case "error":
      console.warn("tessera: coordinator says:", message.message);
      if (steering) messages.say(message.message);
      break;
    default:
      console.warn("tessera: unknown message", message.type);
  }
}

function onBinary(buffer) {
  try {
    if (isVideo(buffer)) video.submit(parseVideo(buffer));
    else compositor.submit(parseFrame(buffer));
  } catch (error) {
    console.warn("tessera: bad frame:", error);
  }
}

function onState({ state: connectionState, detail }) {
  state.connected = connectionState === "open";
  $("status").dataset.state = connectionState;
  document.body.dataset.connection = connectionState;
  const label = { connecting: "connecting…", open: "live", closed: "disconnected", gone: "no such session" };
  $("status-text").textContent = detail && connectionState !== "gone" ? `${label[connectionState]} · ${detail}`
    : label[connectionState];
  if (connectionState === "gone") sessionGone();
}

/** The session does not exist (closed, or a wrong link): the page says so, and stops asking. */
function sessionGone() {
  document.body.dataset.connection = "gone";
  $("status").dataset.state = "closed";
  $("status-text").textContent = "no such session";
  $("gone").hidden = false;
  panel.stop();
  tools.stop();
  animation.hide();
}

function resetView() {
  if (steering && state.bounds) setCamera(frameBounds(state.bounds, state.camera?.fovy_deg ?? 45));
}

const panel = new Panel(document, api, (nodes) => {
  nodeNames.clear();
  for (const node of nodes) nodeNames.set(node.slot, node.name ?? `node ${node.id}`);
  nodeReadback = readbackTiles(nodes);
  if (state.overlay) redrawOverlay();
}, { messages, steering, onStats: (stats) => {
  sessionControls.showStats(stats);
  tools.showStats(stats);
}, onMissing: sessionGone });
const animation = new AnimationControls(document, api, (message) => {
  if (message) messages.say(message);
  else messages.clear();
}, steering);
const connection = new Connection(address(viewSocketPath(session), location.protocol === "https:" ? "wss:" : "ws:"), {
  onText,
  onBinary,
  onState,
});

new ResizeObserver(() => (state.overlay || wallDriver()) && redrawOverlay()).observe(overlayCanvas);

/** A wall cell pings the coordinator this often, to estimate its clock and to count as live (ms). */
const PING_MS = 500;
/** Pings sent at once when a cell (re)joins, for a first clock estimate. */
const FIRST_PINGS = 8;
const clock = new ClockOffset();
const presenter = new Presenter(clock, (frameId) => compositor.present(frameId),
  (frameId, atMs) => connection.send({ type: "presented", frame: frameId, at_ms: atMs }),
  { now: () => performance.now(), requestFrame: (cb) => requestAnimationFrame(cb) });
let pinging = null;
const ping = () => connection.send({ type: "ping", t0: performance.now() });
/** This page is one cell of a wall: full screen, frames held until the coordinator says present. */
function startCell() {
  document.body.dataset.wallCell = "true";
  window.tesseraWall = { presents: () => structuredClone(presenter.log) };
  compositor.hold((frame) => connection.send({ type: "have", frame: frame.frameId }));
  for (let i = 0; i < FIRST_PINGS; i++) setTimeout(ping, i * 50);
  if (pinging === null) pinging = setInterval(ping, PING_MS);
}

/** How long the window must rest before a session's driver asks for frames of its new size (ms). */
const RESIZE_DEBOUNCE_MS = 300;
let sizeTimer = null;
let sizeSent = null;
/** A session's driving viewer asks for frames of its canvas size × devicePixelRatio (the default
 * session keeps the coordinator's --size; watchers letterbox). */
function sendSize() {
  const size = frameSizeFor(frameCanvas.clientWidth, frameCanvas.clientHeight, window.devicePixelRatio);
  if (!size || (sizeSent && size[0] === sizeSent[0] && size[1] === sizeSent[1])) return;
  if (connection.send({ type: "size", size })) sizeSent = size;
}
if (session.key && !session.watching && !session.cell) {
  new ResizeObserver(() => {
    clearTimeout(sizeTimer);
    sizeTimer = setTimeout(sendSize, RESIZE_DEBOUNCE_MS);
  }).observe(frameCanvas);
}
$("toggle-overlay").addEventListener("change", (event) => setOverlay(event.target.checked));
if (steering) {
  $("reset-view").addEventListener("click", resetView);
  frameCanvas.addEventListener("dblclick", resetView);
}
document.addEventListener("keydown", (event) => {
  if (event.target instanceof HTMLInputElement || event.target instanceof HTMLSelectElement) return;
  if (event.key === "o" || event.key === "O") setOverlay(!state.overlay);
  if (event.key === "r" || event.key === "R") resetView();
  if (event.key === "Escape") tools.clear();
});

// The tools (issue 35): a click picks; select, measure, note, cut, the section box, posters and films.
const tools = new Tools(document, { frame: frameCanvas, api, steering, messages,
  view: () => ({ camera: state.camera, size: state.size, bounds: state.bounds }),
  link: (path) => address(sessionApiPath(path, session)) });

const sessionControls = new SessionControls(document, (path, init) => fetch(address(path), init), session,
  messages, (url) => location.assign(url));

connection.start();
if (!session.cell) panel.start();   // a wall cell shows no panel: it polls no stats
sessionControls.start().catch((error) => console.warn("tessera: session controls:", error));
if (!session.cell) tools.start().catch((error) => console.warn("tessera: tools:", error));
setInterval(reportLatency, LATENCY_REPORT_MS);
setInterval(reportStream, STREAM_REPORT_MS);
