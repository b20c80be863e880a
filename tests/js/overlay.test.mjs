// web/overlay.js: letterbox fitting (shared by the overlay and the pan scale) and node colours.
import assert from "node:assert/strict";
import { test } from "node:test";

import { NODE_COLORS, fitFrame, nodeColor, ownershipTiles, readbackTiles } from "../../web/overlay.js";
import { NO_NODE_SLOT } from "../../web/protocol.js";

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

const STATS_NODES = [
  { slot: 0, readback: [[0, 0, 40, 30]] },
  { slot: 1, readback: [[20, 10, 44, 38], [0, 40, 8, 8]] },
  { slot: 2, readback: [] },
  { slot: 3 },
];
const READBACK = [
  { x: 0, y: 0, w: 40, h: 30, node: 0 },
  { x: 20, y: 10, w: 44, h: 38, node: 1 },
  { x: 0, y: 40, w: 8, h: 8, node: 1 },
];

test("stats nodes' readback rects become overlay tiles in their slots", () => {
  assert.deepEqual(readbackTiles(STATS_NODES), READBACK);
  assert.deepEqual(readbackTiles([]), []);
});

test("the overlay outlines the frame's own tiles where each has a node", () => {
  const tiles = [{ x: 0, y: 0, w: 32, h: 48, node: 1 }, { x: 32, y: 0, w: 32, h: 48, node: 0 }];
  assert.deepEqual(ownershipTiles(tiles, READBACK), tiles);
});

test("a merged sort-last frame is outlined by where each node drew", () => {
  const merged = [{ x: 0, y: 0, w: 64, h: 48, node: NO_NODE_SLOT }];
  assert.deepEqual(ownershipTiles(merged, READBACK), READBACK);
});

test("a tile whose node left is not outlined; no frame yet outlines nothing", () => {
  const tiles = [{ x: 0, y: 0, w: 32, h: 48, node: NO_NODE_SLOT }, { x: 32, y: 0, w: 32, h: 48, node: 2 }];
  assert.deepEqual(ownershipTiles(tiles, READBACK), [tiles[1]]);
  assert.deepEqual(ownershipTiles([], READBACK), []);
});
