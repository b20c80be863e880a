// web/latency.js: input → display latency from sequence numbers, its window, intervals and wrap.
import assert from "node:assert/strict";
import { test } from "node:test";

import {
  CameraInput, IDLE_GAP_MS, LatencyTracker, MAX_INPUT_SEQ, MAX_PENDING, WINDOW, nextSeq, quantile, seqAfter,
} from "../../web/latency.js";

test("the first frame answering an input gives its latency; later inputs it covers give none", () => {
  const tracker = new LatencyTracker();
  tracker.sent(1, 100);
  tracker.sent(2, 110);
  tracker.sent(3, 120);
  assert.equal(tracker.drawn(2, 150), 40);
  assert.deepEqual([...tracker.pending.keys()], [3]);
  assert.equal(tracker.drawn(2, 160), null);
  assert.equal(tracker.drawn(1, 170), null);
  assert.equal(tracker.drawn(3, 175), 55);
  assert.equal(tracker.pending.size, 0);
  assert.equal(tracker.summary().samples, 2);
});

test("the still frame, answering the same input again, adds no sample and no interval", () => {
  const tracker = new LatencyTracker();
  tracker.sent(1, 0);
  tracker.drawn(1, 30);
  tracker.sent(2, 20);
  tracker.drawn(2, 50);
  assert.equal(tracker.drawn(2, 260), null);
  assert.deepEqual(tracker.summary(), { p50_ms: 30, p90_ms: 30, samples: 2, interval_ms: 20 });
  assert.equal(tracker.total, 2);
});

test("frames answering no input or an input not sent here give no sample", () => {
  const tracker = new LatencyTracker();
  assert.equal(tracker.drawn(0, 10), null);
  assert.equal(tracker.drawn(7, 20), null);
  assert.equal(tracker.summary(), null);
  tracker.sent(8, 30);
  assert.equal(tracker.drawn(8, 45), 15);
});

test("p50 and p90 interpolate over the newest WINDOW samples", () => {
  assert.equal(quantile([1, 2, 3, 4, 5, 6, 7, 8, 9, 10], 0.5), 5.5);
  assert.ok(Math.abs(quantile([1, 2, 3, 4, 5, 6, 7, 8, 9, 10], 0.9) - 9.1) < 1e-9);
  assert.equal(quantile([4], 0.9), 4);
  const tracker = new LatencyTracker();
  let seq = 0;
  for (let i = 1; i <= WINDOW + 40; i++) {
    seq = nextSeq(seq);
    tracker.sent(seq, i * 1000);
    tracker.drawn(seq, i * 1000 + i);
  }
  const summary = tracker.summary();
  assert.equal(summary.samples, WINDOW);
  assert.equal(tracker.total, WINDOW + 40);
  assert.equal(summary.p50_ms, quantile(Array.from({ length: WINDOW }, (_, i) => 41 + i), 0.5));
  assert.equal(summary.p90_ms, quantile(Array.from({ length: WINDOW }, (_, i) => 41 + i), 0.9));
});

test("the frame interval is the mean gap between answering frames, idle pauses left out", () => {
  const tracker = new LatencyTracker();
  const times = [0, 20, 50, 50 + IDLE_GAP_MS + 1, 60 + IDLE_GAP_MS + 1, 4000];
  times.forEach((time, i) => {
    tracker.sent(i + 1, time - 5);
    tracker.drawn(i + 1, time);
  });
  assert.equal(tracker.summary().interval_ms, (20 + 30 + 10) / 3);
  assert.equal(tracker.intervals.length, 3);
});

test("inputs never answered are kept to MAX_PENDING, the oldest forgotten", () => {
  const tracker = new LatencyTracker();
  for (let seq = 1; seq <= MAX_PENDING * 4; seq++) tracker.sent(seq, seq);
  assert.equal(tracker.pending.size, MAX_PENDING);
  assert.equal(tracker.drawn(1, 5000), null);
  assert.equal(tracker.drawn(MAX_PENDING * 4, 6000), 6000 - MAX_PENDING * 4);
  assert.equal(tracker.pending.size, 0);
});

test("sequence numbers wrap from MAX_INPUT_SEQ to 1 and stay in order", () => {
  assert.equal(nextSeq(0), 1);
  assert.equal(nextSeq(41), 42);
  assert.equal(nextSeq(MAX_INPUT_SEQ), 1);
  assert.ok(seqAfter(1, MAX_INPUT_SEQ));
  assert.ok(!seqAfter(MAX_INPUT_SEQ, 1));
  assert.ok(!seqAfter(5, 5));
  const tracker = new LatencyTracker();
  const before = MAX_INPUT_SEQ - 1;
  const seqs = [before, nextSeq(before), nextSeq(nextSeq(before)), 2];
  assert.deepEqual(seqs, [MAX_INPUT_SEQ - 1, MAX_INPUT_SEQ, 1, 2]);
  seqs.forEach((seq, i) => tracker.sent(seq, i * 10));
  assert.equal(tracker.drawn(MAX_INPUT_SEQ, 25), 15);
  assert.equal(tracker.drawn(1, 40), 20);
  assert.deepEqual([...tracker.pending.keys()], [2]);
  assert.equal(tracker.drawn(MAX_INPUT_SEQ, 45), null);
  assert.equal(tracker.drawn(2, 50), 20);
});

test("camera input sends the newest camera once per tick, numbered, its time tracked; a refused send keeps the number", () => {
  const sent = [];
  const ticks = [];
  let open = true;
  const tracker = new LatencyTracker();
  const input = new CameraInput((message) => open && sent.push(message) > 0, tracker, (tick) => ticks.push(tick),
    () => 500);
  input.set({ eye: [1, 0, 0] });
  input.set({ eye: [2, 0, 0] });
  assert.equal(ticks.length, 1);
  assert.equal(input.pending, true);
  ticks.shift()();
  assert.deepEqual(sent, [{ type: "camera", camera: { eye: [2, 0, 0] }, seq: 1 }]);
  assert.equal(input.pending, false);
  assert.equal(tracker.pending.get(1), 500);
  open = false;
  input.set({ eye: [3, 0, 0] });
  ticks.shift()();
  open = true;
  input.set({ eye: [4, 0, 0] });
  ticks.shift()();
  assert.deepEqual(sent.at(-1), { type: "camera", camera: { eye: [4, 0, 0] }, seq: 2 });
});

test("camera input with a window holds the newest camera while as many inputs are unanswered, timed from its tick", () => {
  const sent = [];
  const ticks = [];
  let clock = 0;
  const tracker = new LatencyTracker();
  const input = new CameraInput((message) => sent.push(message) > 0, tracker, (tick) => ticks.push(tick), () => clock,
    { inFlight: 2, timeoutMs: 1000 });
  for (const eye of [1, 2, 3]) {
    input.set({ eye: [eye, 0, 0] });
    ticks.shift()();
    clock += 16;
  }
  assert.deepEqual(sent.map((m) => m.seq), [1, 2], "two in flight, the third waits");
  assert.equal(input.pending, true, "a camera the coordinator echoes meanwhile is older");
  assert.equal(ticks.length, 1, "a held camera is looked at again next tick");
  input.set({ eye: [4, 0, 0] });
  clock = 100;
  ticks.shift()();   // camera 4 is due from this tick on
  clock = 150;
  input.answered(1);
  assert.deepEqual(sent.at(-1), { type: "camera", camera: { eye: [4, 0, 0] }, seq: 3 });
  assert.equal(tracker.pending.get(3), 100, "timed from when it would have gone without the window");
  assert.equal(input.pending, false);
  input.answered(3);   // answers 2 too
  input.set({ eye: [5, 0, 0] });
  ticks.shift()();
  assert.equal(sent.at(-1).seq, 4);
});

test("camera input with a window stops counting an input unanswered for its timeout", () => {
  const sent = [];
  const ticks = [];
  let clock = 0;
  const input = new CameraInput((message) => sent.push(message) > 0, new LatencyTracker(), (tick) => ticks.push(tick),
    () => clock, { inFlight: 1, timeoutMs: 500 });
  input.set({ eye: [1, 0, 0] });
  ticks.shift()();
  input.set({ eye: [2, 0, 0] });
  clock = 499;
  ticks.shift()();
  assert.equal(sent.length, 1);
  clock = 500;
  ticks.shift()();
  assert.deepEqual(sent.map((m) => m.seq), [1, 2]);
  assert.equal(ticks.length, 0, "nothing waits: no more ticks");
  input.answered(0);   // a frame that answers no input frees nothing
  assert.equal(input.unanswered.length, 1);
});
