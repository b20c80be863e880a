// web/connection.js: the viewer's socket reconnects by itself with back-off; with fakes for
// WebSocket and setTimeout put on globalThis (no browser, no network, no real waiting).
import assert from "node:assert/strict";
import { afterEach, beforeEach, test } from "node:test";

import { CLOSE_NO_SESSION, Connection, FIRST_RETRY_MS, MAX_RETRY_MS, retryDelay } from "../../web/connection.js";

let sockets;
let timers;
const saved = {};

class FakeWebSocket {
  static CONNECTING = 0;
  static OPEN = 1;
  static CLOSED = 3;

  constructor(url) {
    this.url = url;
    this.readyState = FakeWebSocket.CONNECTING;
    this.sent = [];
    sockets.push(this);
  }

  send(text) {
    this.sent.push(text);
  }

  // What the browser does, driven by the test:
  serverOpens() {
    this.readyState = FakeWebSocket.OPEN;
    this.onopen();
  }

  serverSends(data) {
    this.onmessage({ data });
  }

  serverCloses(code, reason = "") {
    this.readyState = FakeWebSocket.CLOSED;
    this.onclose({ code, reason });
  }
}

beforeEach(() => {
  sockets = [];
  timers = [];
  saved.WebSocket = globalThis.WebSocket;
  saved.setTimeout = globalThis.setTimeout;
  globalThis.WebSocket = FakeWebSocket;
  globalThis.setTimeout = (callback, ms) => timers.push({ callback, ms });
});

afterEach(() => {
  globalThis.WebSocket = saved.WebSocket;
  globalThis.setTimeout = saved.setTimeout;
});

function connect() {
  const states = [];
  const texts = [];
  const binaries = [];
  const connection = new Connection("ws://coordinator/ws/view", {
    onText: (message) => texts.push(message),
    onBinary: (buffer) => binaries.push(buffer),
    onState: (state) => states.push(state),
  });
  connection.start();
  return { connection, states, texts, binaries };
}

/** Run the one pending timer (the reconnect) and return its delay. */
function fireTimer() {
  assert.equal(timers.length, 1, "exactly one reconnect is scheduled");
  const { callback, ms } = timers.pop();
  callback();
  return ms;
}

test("retryDelay doubles from FIRST_RETRY_MS up to MAX_RETRY_MS", () => {
  assert.deepEqual([0, 1, 2, 3, 4, 5, 6].map(retryDelay), [500, 1000, 2000, 4000, 8000, 8000, 8000]);
  assert.equal(retryDelay(0), FIRST_RETRY_MS);
  assert.equal(retryDelay(1e6), MAX_RETRY_MS);
});

test("a lost connection reconnects after retryDelay, growing with each failed attempt", () => {
  const { states } = connect();
  assert.equal(sockets.length, 1);
  assert.equal(sockets[0].url, "ws://coordinator/ws/view");
  assert.equal(sockets[0].binaryType, "arraybuffer");
  const delays = [];
  for (let attempt = 0; attempt < 6; attempt++) {
    sockets.at(-1).serverCloses(1006);
    delays.push(fireTimer());
  }
  assert.deepEqual(delays, [0, 1, 2, 3, 4, 5].map(retryDelay));
  assert.equal(sockets.length, 7, "each timer opened a new socket");
  assert.deepEqual(states.slice(0, 3), [
    { state: "connecting", detail: "" },
    { state: "closed", detail: "retry in 0.5 s" },
    { state: "connecting", detail: "" },
  ]);
  assert.deepEqual(states.at(-2), { state: "closed", detail: "retry in 8.0 s" });
});

test("the attempt count resets on a message, not on open", () => {
  connect();
  sockets[0].serverCloses(1006);
  fireTimer();
  sockets[1].serverCloses(1006);
  fireTimer();
  sockets[2].serverOpens();
  sockets[2].serverCloses(4401, "wrong token"); // opened, then refused: still backing off
  assert.equal(fireTimer(), retryDelay(2));
  sockets[3].serverOpens();
  sockets[3].serverSends(JSON.stringify({ type: "hello" }));
  sockets[3].serverCloses(1001);
  assert.equal(fireTimer(), retryDelay(0), "a message proves the connection worked");
});

test("close code 4401 is shown as a wrong token, other closes with their reason", () => {
  const { states } = connect();
  sockets[0].serverCloses(4401, "whatever the server said");
  assert.deepEqual(states.at(-1), { state: "closed", detail: "wrong token · retry in 0.5 s" });
  fireTimer();
  sockets[1].serverCloses(1011, "internal error");
  assert.deepEqual(states.at(-1), { state: "closed", detail: "internal error · retry in 1.0 s" });
  fireTimer();
  sockets[2].serverCloses(1006);
  assert.deepEqual(states.at(-1), { state: "closed", detail: "retry in 2.0 s" });
});

test("a session that does not exist ends the connection: no retry", () => {
  const { states } = connect();
  sockets[0].serverOpens();
  sockets[0].serverCloses(CLOSE_NO_SESSION, "no such session (closed, or a wrong link)");
  assert.deepEqual(states.at(-1), { state: "gone", detail: "no such session (closed, or a wrong link)" });
  assert.equal(timers.length, 0, "nothing scheduled");
  assert.equal(sockets.length, 1);
});

test("messages go to onText (parsed JSON) or onBinary (the ArrayBuffer)", () => {
  const { states, texts, binaries } = connect();
  sockets[0].serverOpens();
  assert.deepEqual(states.at(-1), { state: "open", detail: "" });
  const buffer = new ArrayBuffer(4);
  sockets[0].serverSends('{"type":"scene","bounds":null}');
  sockets[0].serverSends(buffer);
  assert.deepEqual(texts, [{ type: "scene", bounds: null }]);
  assert.deepEqual(binaries, [buffer]);
  assert.equal(binaries[0], buffer);
});

test("send returns false unless the socket is open", () => {
  const notStarted = new Connection("ws://x/ws/view", { onText() {}, onBinary() {}, onState() {} });
  assert.equal(notStarted.send({ type: "camera" }), false);
  const { connection } = connect();
  assert.equal(connection.send({ type: "camera" }), false, "still connecting");
  sockets[0].serverOpens();
  assert.equal(connection.send({ type: "camera", seq: 3 }), true);
  assert.deepEqual(sockets[0].sent, ['{"type":"camera","seq":3}']);
  sockets[0].serverCloses(1006);
  assert.equal(connection.send({ type: "camera" }), false, "closed");
  assert.equal(sockets[0].sent.length, 1);
});
