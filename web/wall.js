// A display wall (issue 22): the clock offset a cell estimates to the coordinator (ping → pong),
// the cells' rects in the whole wall's frame, and the cell outlines the wall's driver draws over
// the whole wall scaled down.

import { fitFrame } from "./overlay.js";

/** Pong samples the clock offset is taken from (the one with the shortest round trip wins). */
export const CLOCK_SAMPLES = 8;

/** The coordinator's clock (ms) minus this page's performance.now(), from ping → pong round trips. */
export class ClockOffset {
  constructor() {
    this.samples = [];
  }

  /**
   * A pong: the ping left at `t0` and came back at `t1` (this page's ms); the coordinator's clock
   * read `clockMs` in between, taken to be halfway.
   */
  sample(t0, t1, clockMs) {
    this.samples.push({ rtt: t1 - t0, offset: clockMs - (t0 + t1) / 2 });
    if (this.samples.length > CLOCK_SAMPLES) this.samples.shift();
  }

  /** The offset of the shortest round trip kept (ms); null before any pong. */
  get offset() {
    if (!this.samples.length) return null;
    return this.samples.reduce((best, s) => (s.rtt < best.rtt ? s : best)).offset;
  }

  /** This page's time `localMs` on the coordinator's clock (null before any pong). */
  toCoordinator(localMs) {
    const offset = this.offset;
    return offset === null ? null : localMs + offset;
  }

  /** The coordinator's time `clockMs` on this page's clock (null before any pong). */
  toLocal(clockMs) {
    const offset = this.offset;
    return offset === null ? null : clockMs - offset;
  }
}

/**
 * Every cell's rect in the whole wall's frame, row by row from the top left.
 * @param {{cols: number, rows: number, cell: [number, number], bezel: [number, number]}} wall
 * @returns {{col: number, row: number, x: number, y: number, w: number, h: number}[]}
 */
export function cellRects(wall) {
  const [w, h] = wall.cell;
  const [bx, by] = wall.bezel ?? [0, 0];
  const rects = [];
  for (let row = 0; row < wall.rows; row++) {
    for (let col = 0; col < wall.cols; col++) rects.push({ col, row, x: col * (w + bx), y: row * (h + by), w, h });
  }
  return rects;
}

/**
 * Outline and label every cell of `wall` on `canvas` (the overlay, covering the letterboxed
 * `width`×`height` frame), over whatever it shows.
 */
export function drawCellOutlines(canvas, width, height, wall) {
  if (!width || !height) return;
  const ratio = window.devicePixelRatio || 1;
  const fit = fitFrame(width, height, canvas.clientWidth, canvas.clientHeight);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.lineWidth = 2;
  ctx.setLineDash([6, 4]);
  ctx.strokeStyle = "#ffffff";
  ctx.fillStyle = "#ffffff";
  ctx.font = "600 12px system-ui, sans-serif";
  ctx.textBaseline = "bottom";
  for (const { col, row, x, y, w, h } of cellRects(wall)) {
    const [left, top] = [fit.x + x * fit.scale, fit.y + y * fit.scale];
    ctx.strokeRect(left + 1, top + 1, w * fit.scale - 2, h * fit.scale - 2);
    ctx.fillText(`cell ${col},${row}`, left + 6, top + h * fit.scale - 6);
  }
  ctx.setLineDash([]);
}
