// Tile overlay: the rectangles of the frame on screen, outlined and tinted per render node.
// Drawn at the screen's resolution (not the frame's), so lines and labels stay crisp.

import { NO_NODE_SLOT } from "./protocol.js";

/** Node colours by node slot: a frame tile's `node`, a stats node's `slot`. */
export const NODE_COLORS = [
  "#4cc9f0", "#f72585", "#ffd166", "#06d6a0", "#b388ff", "#ff8c42", "#90be6d", "#ef476f",
];

export function nodeColor(slot) {
  return NODE_COLORS[slot % NODE_COLORS.length];
}

/**
 * What the overlay outlines ({x, y, w, h, node} each, frame pixels): the frame's tiles by the node
 * that rendered each; when no tile has one node (a sort-last frame, merged from every node's
 * layer), `readback` instead: where each node drew, as the latest `GET /api/stats` reports it
 * (its nodes' `readback` rects, with their `slot`).
 */
export function ownershipTiles(frameTiles, readback) {
  const owned = frameTiles.filter((tile) => tile.node !== NO_NODE_SLOT);
  return owned.length || !frameTiles.length ? owned : readback;
}

/** Each stats node's `readback` rects as overlay tiles ({x, y, w, h, node: its slot}). */
export function readbackTiles(nodes) {
  return nodes.flatMap((node) => (Array.isArray(node.readback) ? node.readback : [])
    .map(([x, y, w, h]) => ({ x, y, w, h, node: node.slot })));
}

/**
 * Where a `width`×`height` frame lands when fitted into a `boxW`×`boxH` box keeping its aspect
 * ratio (letterboxed, centred): scale and offset, in the box's units.
 */
export function fitFrame(width, height, boxW, boxH) {
  const scale = Math.min(boxW / width, boxH / height);
  return { scale, x: (boxW - width * scale) / 2, y: (boxH - height * scale) / 2 };
}

/**
 * Draw the tiles ({x, y, w, h, node}, frame pixels from the top-left) of a `width`×`height`
 * frame on `canvas`, which covers the same box as the letterboxed frame; `tiles = []` clears it.
 * `label(node)` names the node (by slot) in each tile's corner.
 */
export function drawOverlay(canvas, width, height, tiles, label = (node) => `node ${node}`) {
  const ratio = window.devicePixelRatio || 1;
  const [boxW, boxH] = [canvas.clientWidth, canvas.clientHeight];
  canvas.width = Math.round(boxW * ratio);
  canvas.height = Math.round(boxH * ratio);
  if (!tiles.length || !width || !height) return;
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  const fit = fitFrame(width, height, boxW, boxH);
  const line = 1.5;
  ctx.lineWidth = line;
  ctx.font = "600 12px system-ui, sans-serif";
  ctx.textBaseline = "top";
  const boxes = tiles.map((tile) => ({
    x: fit.x + tile.x * fit.scale, y: fit.y + tile.y * fit.scale, w: tile.w * fit.scale, h: tile.h * fit.scale,
    color: nodeColor(tile.node), node: tile.node,
  }));
  // Tints first, outlines and labels over them: rects may overlap (sort-last read-back rects).
  ctx.globalAlpha = 0.1;
  for (const { x, y, w, h, color } of boxes) {
    ctx.fillStyle = color;
    ctx.fillRect(x, y, w, h);
  }
  ctx.globalAlpha = 0.95;
  for (const { x, y, w, h, color, node } of boxes) {
    ctx.strokeStyle = color;
    ctx.fillStyle = color;
    ctx.strokeRect(x + line / 2, y + line / 2, w - line, h - line);
    const text = label(node);
    if (ctx.measureText(text).width + 12 < w && h > 28) ctx.fillText(text, x + 6, y + 6);
  }
  ctx.globalAlpha = 1;
}
