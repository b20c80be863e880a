// web/wall.js and the compositor's held mode (issue 22): a wall cell's clock offset from ping →
// pong, the animation frame a cell presents in, the cells' rects, and decoded frames held until
// the coordinator says present.
import assert from "node:assert/strict";
import { afterEach, beforeEach, test } from "node:test";

import { Compositor, MAX_HELD } from "../../web/compositor.js";
import { Codec } from "../../web/protocol.js";
import { CLOCK_SAMPLES, ClockOffset, DEFAULT_REFRESH_MS, Presenter, cellRects } from "../../web/wall.js";

test("the clock offset is the shortest round trip's, halfway through it", () => {
  const clock = new ClockOffset();
  assert.equal(clock.offset, null);
  assert.equal(clock.toCoordinator(5), null);
  clock.sample(100, 140, 5120);   // rtt 40: offset 5120 - 120 = 5000
  clock.sample(200, 210, 5104);   // rtt 10: offset 5104 - 205 = 4899
  clock.sample(300, 360, 5400);   // rtt 60
  assert.equal(clock.offset, 4899);
  assert.equal(clock.toCoordinator(1000), 5899);
  assert.equal(clock.toLocal(5899), 1000);
  for (let i = 0; i < CLOCK_SAMPLES; i++) clock.sample(1000 + i, 1030 + i, 7015 + i);
  assert.equal(clock.offset, 6000, "old samples leave the window");
});

/** A Presenter on a virtual clock: `frame(ts)` runs the pending animation frame callback at ts. */
function presenterAt(offset) {
  const clock = new ClockOffset();
  clock.sample(0, 0, offset);   // the coordinator's clock = this page's + offset
  const state = { now: 0, callbacks: [], drawn: [], reported: [] };
  const presenter = new Presenter(clock, (frameId) => {
    state.drawn.push(frameId);
    return { frameId };
  }, (frameId, atMs) => state.reported.push([frameId, atMs]), {
    now: () => state.now,
    requestFrame: (cb) => state.callbacks.push(cb),
  });
  const frame = (ts, callbackAt = ts) => {
    state.now = callbackAt;
    const callbacks = state.callbacks.splice(0);
    for (const cb of callbacks) cb(ts);
  };
  return { presenter, state, frame };
}

test("a cell presents in the animation frame whose timestamp is nearest the due time", () => {
  const { presenter, state, frame } = presenterAt(1000);
  state.now = 10;
  presenter.present({ frame: 7, at_ms: 1100 });   // due at 100 on this page's clock
  for (const ts of [16, 32, 48, 64, 80]) frame(ts, ts + 5);
  assert.deepEqual(state.drawn, [], "not before half a refresh ahead of the due time");
  frame(96, 110);   // 4 ms before the due time; its callback runs after it
  assert.deepEqual(state.drawn, [7]);
  assert.deepEqual(state.reported, [[7, 1096]], "the frame's timestamp on the coordinator's clock");
  assert.equal(presenter.refreshMs, 16);
  frame(112);
  assert.equal(state.callbacks.length, 0, "the loop stops once nothing is pending");
  assert.equal(presenter.log.length, 1);
  assert.equal(presenter.log[0].ts, 96);
});

test("two cells whose callbacks run at different times present on the same refresh", () => {
  const fast = presenterAt(0);
  const slow = presenterAt(0);
  for (const cell of [fast, slow]) {
    cell.state.now = 0;
    cell.presenter.present({ frame: 3, at_ms: 50 });
  }
  // the refresh at 33.3 ms is 16.7 ms early; 50 is the one: one page's callback runs at once, the other's late
  for (const ts of [0, 16.7, 33.3, 50, 66.7]) {
    fast.frame(ts, ts + 1);
    slow.frame(ts, ts + 15);
  }
  assert.deepEqual(fast.state.reported, [[3, 50]]);
  assert.deepEqual(slow.state.reported, [[3, 50]]);
});

test("a present that comes late, or a newer one, is drawn on the next animation frame", () => {
  const { presenter, state, frame } = presenterAt(0);
  state.now = 40;
  presenter.present({ frame: 1, at_ms: 20 });   // due before it came
  presenter.present({ frame: 2, at_ms: 30 });   // a newer present replaces it
  frame(48);
  assert.deepEqual(state.drawn, [2]);
  assert.equal(presenter.refreshMs, DEFAULT_REFRESH_MS, "no interval seen yet");
});

test("cells are laid out row by row with the bezels between them", () => {
  const rects = cellRects({ cols: 2, rows: 2, cell: [640, 360], bezel: [20, 10] });
  assert.deepEqual(rects.map(({ col, row }) => [col, row]), [[0, 0], [1, 0], [0, 1], [1, 1]]);
  assert.deepEqual(rects[3], { col: 1, row: 1, x: 660, y: 370, w: 640, h: 360 });
  assert.deepEqual(cellRects({ cols: 3, rows: 1, cell: [10, 5] })[2], { col: 2, row: 0, x: 20, y: 0, w: 10, h: 5 });
});

const saved = {};
class FakeBitmap {
  constructor() {
    this.closed = false;
  }

  close() {
    this.closed = true;
  }
}

beforeEach(() => {
  saved.createImageBitmap = globalThis.createImageBitmap;
  saved.ImageData = globalThis.ImageData;
  globalThis.createImageBitmap = async () => new FakeBitmap();
  globalThis.ImageData = class ImageData {};
});

afterEach(() => {
  globalThis.createImageBitmap = saved.createImageBitmap;
  globalThis.ImageData = saved.ImageData;
});

const settle = () => new Promise((resolve) => setImmediate(resolve));

function held() {
  const calls = [];
  const context = { drawImage: (image, x, y) => calls.push({ image, x, y }), putImageData: () => {} };
  const canvas = { width: 0, height: 0, getContext: () => context };
  const drawn = [];
  const have = [];
  const compositor = new Compositor(canvas, (frame) => drawn.push(frame.frameId), (error) => { throw error; });
  compositor.hold((frame) => have.push(frame.frameId));
  return { compositor, calls, drawn, have };
}

const frame = (frameId) => ({
  frameId, width: 4, height: 2, still: false, inputSeq: 0,
  tiles: [{ x: 0, y: 0, w: 4, h: 2, codec: Codec.PNG, node: 0, bytes: Uint8Array.of(frameId) }],
});

test("a held compositor draws nothing until present, then the frame asked for", async () => {
  const { compositor, calls, drawn, have } = held();
  compositor.submit(frame(3));
  compositor.submit(frame(4));
  await settle();
  assert.deepEqual(have, [3, 4], "each decoded frame is reported");
  assert.equal(calls.length, 0, "nothing on screen before present");
  const first = [...compositor.held.values()][0].images[0];
  assert.equal(compositor.present(3).frameId, 3);
  assert.deepEqual(drawn, [3]);
  assert.ok(first.closed, "a presented frame's images are released");
  assert.deepEqual([...compositor.held.keys()], [4]);
  assert.equal(compositor.present(9).frameId, 4, "the newest held frame not newer than the one asked for");
  assert.equal(compositor.present(10), null, "nothing held");
});

test("a held compositor keeps the newest MAX_HELD frames", async () => {
  const { compositor } = held();
  for (let id = 1; id <= MAX_HELD + 2; id++) {
    compositor.submit(frame(id));
    await settle();
  }
  assert.equal(compositor.held.size, MAX_HELD);
  assert.equal(compositor.present(1).frameId, 3, "frames evicted: the oldest held one is shown");
});
