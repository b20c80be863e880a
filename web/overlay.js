// Tile overlay: the rectangles of the frame on screen, outlined and tinted per render node.
// Drawn at the screen's resolution (not the frame's), so lines and labels stay crisp.

/** Node colours by node slot: a frame tile's `node`, a stats node's `slot`. */
export const NODE_COLORS = [
  "#4cc9f0", "#f72585", "#ffd166", "#06d6a0", "#b388ff", "#ff8c42", "#90be6d", "#ef476f",
];

export function nodeColor(slot) {
  return NODE_COLORS[slot % NODE_COLORS.length];
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
  for (const tile of tiles) {
    const [x, y] = [fit.x + tile.x * fit.scale, fit.y + tile.y * fit.scale];
    const [w, h] = [tile.w * fit.scale, tile.h * fit.scale];
    const color = nodeColor(tile.node);
    ctx.globalAlpha = 0.1;
    ctx.fillStyle = color;
    ctx.fillRect(x, y, w, h);
    ctx.globalAlpha = 0.95;
    ctx.strokeStyle = color;
    ctx.strokeRect(x + line / 2, y + line / 2, w - line, h - line);
    const text = label(tile.node);
    if (ctx.measureText(text).width + 12 < w && h > 28) ctx.fillText(text, x + 6, y + 6);
  }
  ctx.globalAlpha = 1;
}
