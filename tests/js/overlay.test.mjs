// web/overlay.js: letterbox fitting (shared by the overlay and the pan scale) and node colours.
import assert from "node:assert/strict";
import { test } from "node:test";

import { NODE_COLORS, fitFrame, nodeColor } from "../../web/overlay.js";

test("a frame in a taller box fills the width and is centred vertically", () => {
  assert.deepEqual(fitFrame(640, 360, 320, 400), { scale: 0.5, x: 0, y: 110 });
});

test("a frame in a wider box fills the height and is centred horizontally", () => {
  assert.deepEqual(fitFrame(640, 360, 1600, 720), { scale: 2, x: 160, y: 0 });
});

test("node colours are distinct and repeat after the palette", () => {
  assert.equal(new Set(NODE_COLORS).size, NODE_COLORS.length);
  assert.notEqual(nodeColor(0), nodeColor(1));
  assert.equal(nodeColor(NODE_COLORS.length + 1), nodeColor(1));
});
