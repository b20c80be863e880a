// web/video_protocol.js against the golden TVID message of tessera.wire.video.pack_video, and
// web/video.js's VideoStream with a fake WebCodecs VideoDecoder (no browser): key and delta
// frames, a loss asks for one keyframe, a new size reconfigures, only newer frames are painted.
import assert from "node:assert/strict";
import { test } from "node:test";

import { ProtocolError } from "../../web/protocol.js";
import { MAX_DECODE_QUEUE, VideoStream, decodableCodecs } from "../../web/video.js";
import {
  VIDEO_HEADER_SIZE, VIDEO_KEYFRAME, VIDEO_MAGIC, VideoCodec, codecLabel, codecString, isVideo, parseVideo,
} from "../../web/video_protocol.js";

// pack_video(0x01020304, (640, 360), VideoCodec.VP9, True, bytes([0, 0, 0, 1, 0x67, 0x42]),
//            input_seq=0x0A0B0C0D)
const GOLDEN = "54564944020101000403020180020000680100000d0c0b0a000000016742";

function golden() {
  return Uint8Array.from(GOLDEN.match(/../g), (byte) => parseInt(byte, 16)).buffer;
}

test("constants are the wire values", () => {
  assert.equal(VIDEO_MAGIC, "TVID");
  assert.equal(VIDEO_KEYFRAME, 1);
  assert.equal(VIDEO_HEADER_SIZE, 24); // struct "<4sBBBBIIII"
  assert.deepEqual({ ...VideoCodec }, { H264: 0, VP9: 1 });
  assert.deepEqual(Object.values(VideoCodec).map(codecLabel), ["h264", "vp9"]);
});

test("parses the golden keyframe", () => {
  const buffer = golden();
  assert.equal(isVideo(buffer), true);
  const frame = parseVideo(buffer);
  assert.deepEqual({ ...frame, data: [...frame.data] }, {
    frameId: 0x01020304, width: 640, height: 360, codec: VideoCodec.VP9, keyframe: true, inputSeq: 0x0a0b0c0d,
    data: [0, 0, 0, 1, 0x67, 0x42],
  });
});

test("a TFRM frame is not video; malformed video messages are refused", () => {
  assert.equal(isVideo(new TextEncoder().encode("TFRM").buffer), false);
  assert.equal(isVideo(new ArrayBuffer(2)), false);
  const delta = golden();
  new Uint8Array(delta)[5] = 0;
  assert.equal(parseVideo(delta).keyframe, false);
  const cases = {
    "shorter than its header": golden().slice(0, VIDEO_HEADER_SIZE - 1),
    "without an access unit": golden().slice(0, VIDEO_HEADER_SIZE),
  };
  const version = golden();
  new Uint8Array(version)[4] = 9;
  cases["bad video magic/version"] = version;
  const codec = golden();
  new Uint8Array(codec)[6] = 2;
  cases["unknown video codec 2"] = codec;
  for (const [reason, buffer] of Object.entries(cases)) {
    assert.throws(() => parseVideo(buffer), (error) => error instanceof ProtocolError && error.message.includes(reason));
  }
});

// The same values tessera.wire.video.codec_string gives (tests/test_web_mirror.py checks a grid).
test("codec strings name the smallest level that holds the size at 60 fps", () => {
  assert.equal(codecString(VideoCodec.H264, 1280, 720), "avc1.4d4020");
  assert.equal(codecString(VideoCodec.H264, 640, 360), "avc1.4d401f");
  assert.equal(codecString(VideoCodec.H264, 1920, 1080), "avc1.4d402a");
  assert.equal(codecString(VideoCodec.H264, 8192, 8192), "avc1.4d403e");
  assert.equal(codecString(VideoCodec.VP9, 64, 48), "vp09.00.10.08");
  assert.equal(codecString(VideoCodec.VP9, 1920, 1080), "vp09.00.41.08");
});

test("the offer lists the codecs the decoder supports, best first; none without WebCodecs", async () => {
  const asked = [];
  const decoder = {
    isConfigSupported: async (config) => {
      asked.push(config);
      if (config.codec.startsWith("avc1")) throw new TypeError("bad config");
      return { supported: config.codec.startsWith("vp09") };
    },
  };
  assert.deepEqual(await decodableCodecs(1280, 720, decoder), ["vp9"]);
  assert.deepEqual(asked.map((c) => c.codec), ["avc1.4d4020", "vp09.00.40.08"]);
  assert.ok(asked.every((c) => c.codedWidth === 1280 && c.codedHeight === 720 && c.optimizeForLatency));
  assert.deepEqual(await decodableCodecs(1280, 720, { isConfigSupported: async () => ({ supported: true }) }),
    ["h264", "vp9"]);
  assert.deepEqual(await decodableCodecs(1280, 720, undefined), []);
});

/** Every FakeDecoder made, newest last. */
let decoders = [];

class FakeDecoder {
  constructor({ output, error }) {
    this.output = output;
    this.error = error;
    this.state = "unconfigured";
    this.configs = [];
    this.chunks = [];
    this.decodeQueueSize = 0;
    decoders.push(this);
  }

  configure(config) {
    this.configs.push(config);
    this.state = "configured";
  }

  decode(chunk) {
    if (this.state !== "configured") throw new DOMException("not configured", "InvalidStateError");
    this.chunks.push(chunk);
  }

  close() {
    this.state = "closed";
  }

  /** The decoder outputs its chunk `index`. */
  emit(index) {
    const frame = { timestamp: this.chunks[index].timestamp, closed: false, close() { this.closed = true; } };
    this.output(frame);
    return frame;
  }

  /** The decoder fails: it closes, then calls its error callback. */
  fail() {
    this.state = "closed";
    this.error(new DOMException("decode failed", "EncodingError"));
  }
}

class FakeChunk {
  constructor({ type, timestamp, data }) {
    Object.assign(this, { type, timestamp, data });
  }
}

function stream({ paintable = () => true } = {}) {
  decoders = [];
  const calls = [];
  const canvas = {
    width: 0, height: 0,
    getContext: () => ({ drawImage: (image, ...rects) => calls.push({ image, rects }) }),
  };
  const events = { painted: [], requests: 0, errors: 0 };
  const video = new VideoStream(canvas, {
    paintable,
    onPainted: (frame) => events.painted.push(frame.frameId),
    requestKeyframe: () => events.requests++,
    onError: () => events.errors++,
  }, { VideoDecoder: FakeDecoder, EncodedVideoChunk: FakeChunk });
  video.choose({ transport: "h264", codec: "avc1.4d401f" });
  return { video, canvas, calls, events };
}

const frame = (frameId, keyframe, width = 640, height = 360) => ({
  frameId, width, height, codec: VideoCodec.H264, keyframe, inputSeq: frameId, data: new Uint8Array(10),
});

test("a keyframe configures the decoder with the stream's codec and colours; decoded frames are painted and closed", () => {
  const { video, canvas, calls, events } = stream();
  video.submit(frame(5, true));
  video.submit(frame(6, false));
  assert.equal(decoders.length, 1);
  assert.deepEqual(decoders[0].configs, [
    { codec: "avc1.4d401f", codedWidth: 640, codedHeight: 360, optimizeForLatency: true,
      colorSpace: { primaries: "bt709", transfer: "iec61966-2-1", matrix: "smpte170m", fullRange: true } },
  ]);
  assert.deepEqual(decoders[0].chunks.map((c) => c.type), ["key", "delta"]);
  const painted = [decoders[0].emit(0), decoders[0].emit(1)];
  assert.deepEqual(events.painted, [5, 6]);
  assert.deepEqual([canvas.width, canvas.height], [640, 360]);
  assert.deepEqual(calls.map(({ rects }) => rects), [[0, 0, 640, 360, 0, 0, 640, 360], [0, 0, 640, 360, 0, 0, 640, 360]]);
  assert.ok(painted.every((f) => f.closed));
  assert.equal(video.decoded, 2);
  assert.equal(video.painted, 2);
  assert.equal(events.requests, 0);
});

test("a frame older than the one shown is decoded but not painted, and closed", () => {
  let shown = 7;
  const { video, events } = stream({ paintable: (frameId) => frameId > shown });
  video.submit(frame(6, true));
  const old = decoders[0].emit(0);
  assert.deepEqual(events.painted, []);
  assert.ok(old.closed);
  video.submit(frame(8, false));
  decoders[0].emit(1);
  shown = 8;
  assert.deepEqual(events.painted, [8]);
});

test("delta frames before the first keyframe are dropped and ask for one keyframe", () => {
  const { video, events } = stream();
  video.submit(frame(1, false));
  video.submit(frame(2, false));
  assert.equal(decoders.length, 0);
  assert.equal(video.dropped, 2);
  assert.equal(events.requests, 1);
  video.submit(frame(3, true));
  assert.equal(decoders[0].chunks.length, 1);
});

test("a full decode queue drops the delta: one keyframe request per loss, deltas wait for the keyframe", () => {
  const { video, events } = stream();
  video.submit(frame(1, true));
  decoders[0].decodeQueueSize = MAX_DECODE_QUEUE + 1;
  video.submit(frame(2, false));
  decoders[0].decodeQueueSize = 0;
  video.submit(frame(3, false));
  video.submit(frame(4, false));
  assert.equal(events.requests, 1);
  assert.equal(video.dropped, 3);
  assert.equal(decoders[0].chunks.length, 1);
  video.submit(frame(5, true));
  video.submit(frame(6, false));
  assert.deepEqual(decoders[0].chunks.map((c) => c.type), ["key", "key", "delta"]);
  assert.equal(decoders[0].configs.length, 1, "the same codec and size keeps the configuration");
  decoders[0].decodeQueueSize = MAX_DECODE_QUEUE + 1;
  video.submit(frame(7, false));
  assert.equal(events.requests, 2, "a second loss asks again");
});

test("a decoder error asks for a keyframe once; the keyframe gets a new decoder", () => {
  const { video, events } = stream();
  video.submit(frame(1, true));
  video.submit(frame(2, false));
  decoders[0].fail();
  video.submit(frame(3, false));
  assert.equal(events.errors, 1);
  assert.equal(events.requests, 1);
  assert.equal(video.dropped, 1);
  video.submit(frame(4, true));
  assert.equal(decoders.length, 2);
  assert.equal(decoders[1].chunks[0].type, "key");
  decoders[1].emit(0);
  assert.deepEqual(events.painted, [4]);
});

test("a keyframe of another size reconfigures the decoder; tiles close it", () => {
  const { video, canvas } = stream();
  video.submit(frame(1, true));
  video.choose({ transport: "h264", codec: "avc1.4d4020" });
  video.submit(frame(2, true, 1280, 720));
  assert.equal(decoders.length, 1);
  assert.deepEqual(decoders[0].configs.map((c) => [c.codec, c.codedWidth, c.codedHeight]),
    [["avc1.4d401f", 640, 360], ["avc1.4d4020", 1280, 720]]);
  decoders[0].emit(1);
  assert.deepEqual([canvas.width, canvas.height], [1280, 720]);
  video.choose({ transport: "tiles", codec: null });
  assert.equal(video.active, false);
  assert.equal(decoders[0].state, "closed");
});

test("the report gives bytes and decoded frames per second over its window, the queue, drops, the last frame", () => {
  const { video } = stream();
  assert.deepEqual(video.report(1000),
    { bytes_per_s: 0, decoded_fps: 0, decode_queue: 0, frames_dropped: 0, frame: null });
  video.submit(frame(1, true));
  video.submit(frame(2, false));
  decoders[0].emit(0);
  decoders[0].decodeQueueSize = 1;
  video.submit(frame(3, true));
  const report = video.report(1500);
  assert.deepEqual(report, {
    bytes_per_s: (3 * (VIDEO_HEADER_SIZE + 10)) / 0.5, decoded_fps: 2, decode_queue: 1, frames_dropped: 0, frame: 3,
  });
  assert.equal(video.report(2500).bytes_per_s, 0);
});
