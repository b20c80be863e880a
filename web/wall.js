// A display wall (issue 22): the clock offset a cell estimates to the coordinator (ping → pong),
// when a cell presents the frame the coordinator names (Presenter), the cells' rects in the whole
// wall's frame, and the cell outlines the wall's driver draws over the whole wall scaled down.

import { fitFrame } from "./overlay.js";

/**
 * Pong samples the clock offset is taken from (the one with the shortest round trip wins): with a
 * ping each 500 ms, the last 8 s. Under load most round trips are long and lopsided (bench.wall
 * saw the estimate jump by up to 30 ms with 8 samples); a longer window holds a short one more
 * often, and clocks of two machines drift apart by under 1 ms in it (100 ppm).
 */
export const CLOCK_SAMPLES = 16;

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

/** Presents kept in a Presenter's log (for bench.wall). */
export const PRESENT_LOG = 600;
/** The display refresh interval assumed until two animation frames have been seen (ms). */
export const DEFAULT_REFRESH_MS = 1000 / 60;
/** Animation frame intervals the refresh interval is estimated from (the shortest wins). */
const REFRESH_SAMPLES = 8;

/**
 * A wall cell's presents. On the coordinator's `present` ({frame, at_ms}) it runs an animation
 * frame loop and draws the held frame in the animation frame whose timestamp is nearest the due
 * time (at_ms on this page's estimate of the coordinator's clock): the first whose timestamp is
 * at least half a refresh before it. A timestamp is when the frame began, the same on every page
 * driven by the same display, however late the page's callback for it runs; so cells pick the same
 * refresh, where "the first callback after a timer at the due time" lands a refresh apart when a
 * callback of the frame has run on one page and not yet on another. The frame's timestamp on the
 * coordinator's clock is reported. `log` keeps each present's times (this page's ms): received,
 * due, the animation frame's timestamp, when its callback ran, drawn, and the clock offset then.
 */
export class Presenter {
  /**
   * @param {ClockOffset} clock
   * @param {(frameId: number) => object | null} present  draws the held frame (Compositor.present)
   * @param {(frameId: number, atMs: number) => void} report  the frame is on screen at atMs (coordinator ms)
   * @param {{now: () => number, requestFrame: (cb: (ts: number) => void) => void}} timing
   */
  constructor(clock, present, report, timing) {
    this.clock = clock;
    this.draw = present;
    this.report = report;
    this.timing = timing;
    this.log = [];
    /** The present waiting for its animation frame (a newer one replaces it), null: none. */
    this.pending = null;
    this.looping = false;
    this.lastTs = null;
    this.intervals = [];
  }

  /** The display's refresh interval (ms): the shortest of the last animation frame intervals. */
  get refreshMs() {
    return this.intervals.length ? Math.min(...this.intervals) : DEFAULT_REFRESH_MS;
  }

  /** The coordinator's `present` message. */
  present(message) {
    const received = this.timing.now();
    this.pending = { frame: message.frame, atMs: message.at_ms, received, due: this.clock.toLocal(message.at_ms) };
    if (!this.looping) {
      this.looping = true;
      this.timing.requestFrame((ts) => this.onFrame(ts));
    }
  }

  onFrame(ts) {
    if (this.lastTs !== null && ts > this.lastTs) {
      this.intervals.push(ts - this.lastTs);
      if (this.intervals.length > REFRESH_SAMPLES) this.intervals.shift();
    }
    this.lastTs = ts;
    const entry = this.pending;
    if (entry !== null && (entry.due === null || ts >= entry.due - this.refreshMs / 2)) {
      this.pending = null;
      const callback = this.timing.now();
      const frame = this.draw(entry.frame);
      Object.assign(entry, { ts, callback, drawn: this.timing.now(), offset: this.clock.offset });
      const atMs = frame && this.clock.toCoordinator(ts);
      if (atMs !== null && atMs >= 0) this.report(frame.frameId, atMs);
      this.log.push(entry);
      if (this.log.length > PRESENT_LOG) this.log.shift();
    }
    // one animation frame more after a present (an interval sample); then the loop stops till the next
    if (entry === null) {
      this.looping = false;
      this.lastTs = null;
    } else {
      this.timing.requestFrame((next) => this.onFrame(next));
    }
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
