// web/compositor.js: frames decode concurrently and are drawn whole, newest wins; with fakes for
// createImageBitmap, ImageData and the canvas put on globalThis (no browser).
import assert from "node:assert/strict";
import { afterEach, beforeEach, test } from "node:test";

import { Compositor, MAX_DECODING } from "../../web/compositor.js";
import { Codec, ProtocolError } from "../../web/protocol.js";

/** Every createImageBitmap call, in order, to be resolved or rejected by the test. */
let decodes;
const saved = {};

class FakeImageData {
  constructor(data, width, height) {
    this.data = data;
    this.width = width;
    this.height = height;
  }
}

class FakeBitmap {
  constructor(blob) {
    this.blob = blob;
    this.closed = false;
  }

  close() {
    this.closed = true;
  }
}

beforeEach(() => {
  decodes = [];
  saved.ImageData = globalThis.ImageData;
  saved.createImageBitmap = globalThis.createImageBitmap;
  globalThis.ImageData = FakeImageData;
  globalThis.createImageBitmap = (blob) =>
    new Promise((resolve, reject) => {
      const bitmap = new FakeBitmap(blob);
      decodes.push({ blob, bitmap, resolve: () => resolve(bitmap), reject });
    });
});

afterEach(() => {
  globalThis.ImageData = saved.ImageData;
  globalThis.createImageBitmap = saved.createImageBitmap;
});

/** Let pending promise callbacks run. */
const settle = () => new Promise((resolve) => setImmediate(resolve));

function fakeCanvas() {
  const calls = [];
  const context = {
    putImageData: (image, x, y) => calls.push({ op: "put", image, x, y }),
    drawImage: (image, x, y, w, h) => calls.push({ op: "draw", image, x, y, w, h }),
  };
  return { width: 0, height: 0, calls, getContext: () => context };
}

function setup() {
  const canvas = fakeCanvas();
  const drawn = [];
  const errors = [];
  const compositor = new Compositor(canvas, (frame) => drawn.push(frame.frameId), (error) => errors.push(error));
  return { canvas, compositor, drawn, errors };
}

function jpegFrame(frameId, tileCount = 1) {
  const tiles = Array.from({ length: tileCount }, (_, i) => ({
    x: 8 * i, y: 0, w: 8, h: 4, codec: Codec.JPEG, node: i, bytes: Uint8Array.of(0xff, 0xd8, frameId, i),
  }));
  return { frameId, width: 8 * tileCount, height: 4, still: false, inputSeq: 0, tiles };
}

test("a newer frame decoded first is not overwritten by an older one", async () => {
  const { canvas, compositor, drawn } = setup();
  compositor.submit(jpegFrame(1));
  compositor.submit(jpegFrame(2));
  assert.equal(decodes.length, 2, "both frames decode at once");
  decodes[1].resolve();
  await settle();
  assert.deepEqual(drawn, [2]);
  decodes[0].resolve();
  await settle();
  assert.deepEqual(drawn, [2], "the older frame is dropped, not drawn over the newer");
  assert.equal(compositor.dropped, 1);
  assert.deepEqual(canvas.calls.map((c) => c.image), [decodes[1].bitmap]);
  assert.ok(decodes[0].bitmap.closed && decodes[1].bitmap.closed, "bitmaps are released either way");
});

test("a frame that is no longer drawable (the video path painted a newer one) is dropped", async () => {
  const { compositor, drawn } = setup();
  let shown = 0;
  compositor.drawable = (frame) => frame.frameId > shown;
  compositor.submit(jpegFrame(5));
  shown = 6;
  decodes[0].resolve();
  await settle();
  assert.deepEqual(drawn, []);
  assert.equal(compositor.dropped, 1);
  assert.ok(decodes[0].bitmap.closed);
  compositor.submit(jpegFrame(7));
  decodes[1].resolve();
  await settle();
  assert.deepEqual(drawn, [7]);
});

test("at most MAX_DECODING frames decode at once; the waiting slot keeps only the newest", async () => {
  const { compositor, drawn } = setup();
  const total = MAX_DECODING + 3;
  for (let id = 1; id <= total; id++) compositor.submit(jpegFrame(id));
  assert.equal(decodes.length, MAX_DECODING);
  assert.equal(compositor.waiting.frameId, total, "the newest frame waits");
  assert.equal(compositor.dropped, 2, "the frames it replaced in the slot are dropped");

  decodes[0].resolve();
  await settle();
  assert.deepEqual(drawn, [1]);
  assert.equal(decodes.length, MAX_DECODING + 1, "a freed decoder takes the waiting frame");
  assert.equal(compositor.waiting, null);
  assert.equal(new Uint8Array(await decodes.at(-1).blob.arrayBuffer())[2], total);

  decodes.at(-1).resolve();
  await settle();
  for (const decode of decodes.slice(1, MAX_DECODING)) decode.resolve();
  await settle();
  assert.deepEqual(drawn, [1, total], "frames older than the one drawn are dropped");
  assert.equal(compositor.dropped, 2 + (MAX_DECODING - 1));
  assert.equal(compositor.decoding, 0);
});

test("a decode error drops the frame, reports it and releases the tiles that decoded", async () => {
  const { canvas, compositor, drawn, errors } = setup();
  compositor.submit(jpegFrame(1, 2));
  decodes[0].resolve();
  decodes[1].reject(new Error("broken JPEG"));
  await settle();
  await settle();
  assert.deepEqual(drawn, []);
  assert.deepEqual(errors.map((e) => e.message), ["broken JPEG"]);
  assert.equal(compositor.dropped, 1);
  assert.equal(canvas.calls.length, 0, "nothing of the broken frame is drawn");
  assert.ok(decodes[0].bitmap.closed, "the tile that decoded is released");

  compositor.submit(jpegFrame(2));
  decodes[2].resolve();
  await settle();
  assert.deepEqual(drawn, [2], "the next frame is drawn as usual");
});

test("raw tiles are put as RGBA, encoded tiles drawn scaled into their rect; the canvas takes the frame size", async () => {
  const { canvas, compositor, drawn } = setup();
  const frame = {
    frameId: 7, width: 3, height: 2, still: true, inputSeq: 0,
    tiles: [
      { x: 0, y: 0, w: 1, h: 2, codec: Codec.RAW, node: 0, bytes: Uint8Array.of(1, 2, 3, 4, 5, 6) },
      { x: 1, y: 0, w: 2, h: 2, codec: Codec.PNG, node: 1, bytes: Uint8Array.of(0x89, 0x50) },
    ],
  };
  compositor.submit(frame);
  assert.equal(decodes.length, 1, "only the PNG tile goes to createImageBitmap");
  assert.equal(decodes[0].blob.type, "image/png");
  decodes[0].resolve();
  await settle();
  assert.deepEqual(drawn, [7]);
  assert.deepEqual([canvas.width, canvas.height], [3, 2]);
  const [put, draw] = canvas.calls;
  assert.equal(put.op, "put");
  assert.ok(put.image instanceof FakeImageData);
  assert.deepEqual([put.x, put.y, put.image.width, put.image.height], [0, 0, 1, 2]);
  assert.deepEqual([...put.image.data], [1, 2, 3, 255, 4, 5, 6, 255]);
  assert.deepEqual({ ...draw, image: undefined }, { op: "draw", image: undefined, x: 1, y: 0, w: 2, h: 2 });
  assert.equal(draw.image, decodes[0].bitmap);
});

test("a raw tile of the wrong length is a decode error", async () => {
  const { compositor, drawn, errors } = setup();
  compositor.submit({
    frameId: 1, width: 2, height: 1, still: false, inputSeq: 0,
    tiles: [{ x: 0, y: 0, w: 2, h: 1, codec: Codec.RAW, node: 0, bytes: new Uint8Array(5) }],
  });
  await settle();
  assert.deepEqual(drawn, []);
  assert.equal(errors.length, 1);
  assert.ok(errors[0] instanceof ProtocolError);
  assert.equal(compositor.decoding, 0);
});
