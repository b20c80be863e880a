// web/protocol.js against the golden TFRM frame that tests/test_protocol_golden.py pins on the
// Python side (tessera.protocol.pack_frame), plus the raw-tile RGB→RGBA expansion.
import assert from "node:assert/strict";
import { test } from "node:test";

import { rgbToRgba } from "../../web/compositor.js";
import {
  Codec, FRAME_HEADER_SIZE, FRAME_MAGIC, FRAME_SAMPLES_SHIFT, FRAME_STILL, FRAME_TILE_SIZE, PROTOCOL_VERSION,
  ProtocolError,
  parseFrame,
} from "../../web/protocol.js";

// pack_frame(0x01020304, (4, 2), [(Rect(0, 0, 2, 2), RAW, 0, bytes(range(10, 22))),
//                                 (Rect(2, 0, 2, 2), JPEG, 0x0201, b"\xff\xd8\xff\xd9")],
//            still=True, input_seq=0x0A0B0C0D)
const GOLDEN =
  "5446524d020102000403020104000000020000000d0c0b0a00000000000000000200000002000000000000000c000000" +
  "0200000000000000020000000200000001000102040000000a0b0c0d0e0f101112131415ffd8ffd9";

function golden() {
  const bytes = Uint8Array.from(GOLDEN.match(/../g), (byte) => parseInt(byte, 16));
  return bytes.buffer;
}

// tests/test_web_mirror.py checks these constants against tessera/protocol.py itself.
test("constants are the wire values", () => {
  assert.equal(FRAME_MAGIC, "TFRM");
  assert.equal(PROTOCOL_VERSION, 2);
  assert.equal(FRAME_HEADER_SIZE, 24); // struct "<4sBBHIIII"
  assert.equal(FRAME_TILE_SIZE, 24); // struct "<IIIIBBHI"
  assert.equal(FRAME_STILL, 1);
  assert.equal(FRAME_SAMPLES_SHIFT, 1);
  assert.deepEqual({ ...Codec }, { RAW: 0, JPEG: 1, PNG: 2 });
});

test("parses the golden two-tile still frame", () => {
  const frame = parseFrame(golden());
  assert.equal(frame.frameId, 0x01020304);
  assert.equal(frame.width, 4);
  assert.equal(frame.height, 2);
  assert.equal(frame.still, true);
  assert.equal(frame.inputSeq, 0x0a0b0c0d);
  assert.equal(frame.tiles.length, 2);
  const [raw, jpeg] = frame.tiles;
  assert.deepEqual(
    { x: raw.x, y: raw.y, w: raw.w, h: raw.h, codec: raw.codec, node: raw.node },
    { x: 0, y: 0, w: 2, h: 2, codec: Codec.RAW, node: 0 },
  );
  assert.deepEqual([...raw.bytes], Array.from({ length: 12 }, (_, i) => 10 + i));
  assert.deepEqual(
    { x: jpeg.x, y: jpeg.y, w: jpeg.w, h: jpeg.h, codec: jpeg.codec, node: jpeg.node },
    { x: 2, y: 0, w: 2, h: 2, codec: Codec.JPEG, node: 0x0201 },
  );
  assert.deepEqual([...jpeg.bytes], [0xff, 0xd8, 0xff, 0xd9]);
});

test("a frame without the still flag is interactive", () => {
  const buffer = golden();
  new Uint8Array(buffer)[5] = 0;
  assert.equal(parseFrame(buffer).still, false);
});

test("rejects bad magic, version, codec and lengths", () => {
  const corrupt = (at, value) => {
    const buffer = golden();
    new Uint8Array(buffer)[at] = value;
    return buffer;
  };
  assert.throws(() => parseFrame(corrupt(0, 0x58)), ProtocolError); // magic "XFRM"
  assert.throws(() => parseFrame(corrupt(4, 1)), ProtocolError); // version 1
  assert.throws(() => parseFrame(corrupt(FRAME_HEADER_SIZE + 16, 9)), /unknown tile codec 9/);
  assert.throws(() => parseFrame(golden().slice(0, FRAME_HEADER_SIZE - 1)), /shorter than its header/);
  assert.throws(() => parseFrame(golden().slice(0, FRAME_HEADER_SIZE + FRAME_TILE_SIZE)), /tile table/);
  assert.throws(() => parseFrame(golden().slice(0, -1)), /does not match its tile table/);
  const longer = new Uint8Array(golden().byteLength + 1);
  longer.set(new Uint8Array(golden()));
  assert.throws(() => parseFrame(longer.buffer), /does not match its tile table/);
});

test("raw tiles expand to RGBA with opaque alpha", () => {
  const rgba = rgbToRgba(Uint8Array.from([1, 2, 3, 4, 5, 6]), 2, 1);
  assert.deepEqual([...rgba], [1, 2, 3, 255, 4, 5, 6, 255]);
  assert.throws(() => rgbToRgba(new Uint8Array(5), 2, 1), ProtocolError);
});

test("a progressive still's frames say their samples in flags bits 1-7", () => {
  const refining = golden();
  new DataView(refining).setUint8(5, 5 << FRAME_SAMPLES_SHIFT);
  assert.deepEqual([parseFrame(refining).samples, parseFrame(refining).still], [5, false]);
  const converged = golden();
  new DataView(converged).setUint8(5, (8 << FRAME_SAMPLES_SHIFT) | FRAME_STILL);
  assert.deepEqual([parseFrame(converged).samples, parseFrame(converged).still], [8, true]);
  assert.equal(parseFrame(golden()).samples, 0);
});
