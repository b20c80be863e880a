// web/panel.js: the timing bars' scale and stacked segment widths, node lines, the input latency
// figure, the transport figure.
import assert from "node:assert/strict";
import { test } from "node:test";

import {
  PHASES, PHASE_MEANING, atRest, detailText, fpsText, inputLatencyText, loadingText, niceScale, nodeDetail,
  nodeDetailTitle, stillText, segmentWidths, transportText,
} from "../../web/panel.js";

// PHASES against tessera.protocol.NODE_PHASES: tests/test_web_mirror.py reads both and compares them.
test("one bar segment per phase, in PHASES order", () => {
  const node = Object.fromEntries(PHASES.map((phase, i) => [`${phase}_ms`, i + 1]));
  assert.deepEqual(segmentWidths(node, 10), PHASES.map((_, i) => 10 * (i + 1)));
});

test("niceScale rounds up to 1, 2 or 5 × 10^k", () => {
  assert.equal(niceScale(0.7), 1);
  assert.equal(niceScale(1), 1);
  assert.equal(niceScale(1.01), 2);
  assert.equal(niceScale(13.4), 20);
  assert.equal(niceScale(20), 20);
  assert.equal(niceScale(37), 50);
  assert.equal(niceScale(51), 100);
  assert.equal(niceScale(0), 1);
  assert.equal(niceScale(Number.NaN), 1);
});

test("segment widths are percentages of the full scale, missing phases count 0", () => {
  const node = { render_ms: 10, readback_ms: 2.5, encode_ms: 5, send_ms: 2.5 };
  assert.deepEqual(segmentWidths(node, 40), [25, 6.25, 12.5, 6.25]);
  assert.deepEqual(segmentWidths({ render_ms: 4 }, 8), [50, 0, 0, 0]);
  assert.deepEqual(segmentWidths({ render_ms: -3, send_ms: "x" }, 8), [0, 0, 0, 0]);
});

test("node detail: timings when ready, the speed where speeds differ, the loading state otherwise", () => {
  const ready = { state: "ready", busy_ms: 12.345, tiles: [[0, 0, 1, 1], [1, 0, 1, 1]], speed: 3.1, speed_distinct: true };
  assert.equal(nodeDetail(ready), "12.3 ms · 2 tiles · ×3.10");
  assert.equal(nodeDetail({ busy_ms: 1, tiles: [[0, 0, 1, 1]], speed: 1, speed_distinct: true }), "1.0 ms · 1 tile · ×1.00");
  assert.equal(nodeDetail({ ...ready, speed: 1, speed_distinct: false }), "12.3 ms · 2 tiles", "the same speed: none shown");
  assert.equal(nodeDetail({ state: "loading", scene_progress: 0.456 }), "loading 46%");
});

test("input → display latency: p50 in ms and in frame intervals", () => {
  assert.equal(inputLatencyText({ p50_ms: 48.2, p90_ms: 70, samples: 12, interval_ms: 37.5 }), "48 ms · 1.3 fr");
  assert.equal(inputLatencyText({ p50_ms: 31, p90_ms: 31, samples: 1, interval_ms: 0 }), "31 ms");
  assert.equal(inputLatencyText({ p50_ms: 0, p90_ms: 0, samples: 0, interval_ms: 0 }), "–");
  assert.equal(inputLatencyText(null), "–");
});

test("at rest: no frame for 2 s (fps 0) and none in flight; the fps figure says so", () => {
  assert.equal(atRest({ fps: 0, frames_in_flight: 0 }), true);
  assert.equal(atRest({ fps: 0 }), true);
  assert.equal(atRest({ fps: 0, frames_in_flight: 1 }), false);
  assert.equal(atRest({ fps: 24.5, frames_in_flight: 0 }), false);
  assert.equal(fpsText({ fps: 0, frames_in_flight: 0 }), "at rest");
  assert.equal(fpsText({ fps: 24.46, frames_in_flight: 2 }), "24.5");
  assert.equal(fpsText({ fps: 0, frames_in_flight: 1 }), "0.0");
});

test("a node line's hover text explains its busy time, tiles and speed factor", () => {
  const node = { name: "n1", busy_ms: 12.34, tiles: [[0, 0, 8, 8], [8, 0, 8, 8]], speed: 1.51, speed_distinct: true,
    calibration_spread: 0.042 };
  const lines = nodeDetailTitle(node).split("\n");
  assert.equal(lines.length, 3);
  assert.match(lines[0], /^12\.3 ms: n1's time for its part of the last frame/);
  assert.match(lines[1], /^2 tiles: /);
  assert.match(lines[2], /^×1\.51: its speed measured at start-up \(±4 %\), relative to the slowest node/);
  const same = nodeDetailTitle({ ...node, speed: 1, speed_distinct: false }).split("\n")[2];
  assert.match(same, /^its speed measured at start-up \(±4 %\) is the others' .* no factor is shown/);
  assert.match(nodeDetailTitle({ id: 3, state: "loading" }), /^node 3 is loading: /);
});

test("every bar phase has a meaning", () => {
  assert.deepEqual(Object.keys(PHASE_MEANING), PHASES);
  for (const phase of PHASES) assert.ok(PHASE_MEANING[phase].length > 10);
});

test("the transport figure names tiles, or the codec with the stream's target", () => {
  assert.equal(transportText(undefined, null), "–");
  assert.equal(transportText("tiles", null), "tiles");
  assert.equal(transportText("h264", null), "h264");
  assert.equal(transportText("h264", { bitrate: 2_500_000, max_fps: 60 }), "h264 · 2.5 Mbit/s · 60 fps");
});

test("the still figure says the samples the picture holds and their estimated PSNR", () => {
  assert.equal(stillText({ still: false, still_samples: { done: 0, estimated_psnr_db: null } }), "–");
  assert.equal(stillText({}), "–");
  assert.equal(stillText({ still: true, still_samples: { done: 16, estimated_psnr_db: 49.34 } }), "16 samples · ≈49.3 dB");
  assert.equal(stillText({ still: false, still_samples: { done: 5, estimated_psnr_db: null } }), "5 samples (refining)");
  assert.equal(stillText({ still: true, still_samples: { done: 1 } }), "1 sample");
});

test("the detail figure says the levels-of-detail bound, or full detail", () => {
  assert.equal(detailText({ lod_error_px: 0.5 }), "≤ 0.50 px");
  assert.equal(detailText({ lod_error_px: null }), "full");
  assert.equal(detailText({}), "full");
});

test("the detail figure of a point cloud says its moving frames' point budget", () => {
  assert.equal(detailText({ point_budget: 300000, lod_error_px: 0.5 }), "≤ 300k points");
  assert.equal(detailText({ point_budget: 1500000 }), "≤ 1.50M points");
  assert.equal(detailText({ point_budget: null, lod_error_px: null }), "full");
});

test("the loading line says the stage and how many nodes hold the scene", () => {
  assert.equal(loadingText(null), "");
  assert.equal(loadingText({ fraction: 0.42, message: "reading big.ply", nodes_ready: 1, nodes: 3 }),
               "loading 42 %: reading big.ply (1 of 3 nodes ready)");
});
