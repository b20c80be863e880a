// Turns parsed TFRM frames into pixels on a canvas: every tile of a frame is decoded first, then
// all are drawn in one synchronous pass, so the canvas never shows a frame half old, half new.
// Frames decode concurrently (the browser decodes images off the main thread); a decoded frame
// is drawn only if no newer frame has been drawn meanwhile, otherwise it is dropped.
// Held (a display wall's cell, issue 22): a decoded frame is kept, not drawn, until the coordinator
// says every cell holds it (present(frameId)), so all cells swap together; the newest few are kept.

import { Codec, ProtocolError } from "./protocol.js";

/** Frames decoding at once; a frame arriving beyond this waits in a one-frame slot (latest wins). */
export const MAX_DECODING = 3;
/** Decoded frames a held compositor keeps while it waits for the coordinator's present. */
export const MAX_HELD = 8;
const MIME = { [Codec.JPEG]: "image/jpeg", [Codec.PNG]: "image/png" };

/** Raw tile pixels (w×h×3 bytes, RGB, rows top-down) → RGBA bytes with alpha 255. */
export function rgbToRgba(rgb, w, h) {
  if (rgb.length !== w * h * 3) {
    throw new ProtocolError(`raw tile has ${rgb.length} bytes, expected ${w * h * 3}`);
  }
  const rgba = new Uint8ClampedArray(w * h * 4);
  for (let src = 0, dst = 0; src < rgb.length; src += 3, dst += 4) {
    rgba[dst] = rgb[src];
    rgba[dst + 1] = rgb[src + 1];
    rgba[dst + 2] = rgb[src + 2];
    rgba[dst + 3] = 255;
  }
  return rgba;
}

/** One tile → ImageData (raw) or ImageBitmap (JPEG, PNG). */
async function decodeTile(tile) {
  if (tile.codec === Codec.RAW) {
    return new ImageData(rgbToRgba(tile.bytes, tile.w, tile.h), tile.w, tile.h);
  }
  return createImageBitmap(new Blob([tile.bytes], { type: MIME[tile.codec] }));
}

function release(images) {
  for (const image of images) {
    if (image && typeof image.close === "function") image.close();
  }
}

export class Compositor {
  /**
   * @param {HTMLCanvasElement} canvas  resized to each frame's width × height
   * @param {(frame: object) => void} onDrawn  called after a frame is on the canvas
   * @param {(error: Error) => void} onError  a frame that could not be decoded (dropped)
   */
  constructor(canvas, onDrawn, onError) {
    this.canvas = canvas;
    this.context = canvas.getContext("2d", { alpha: false });
    this.onDrawn = onDrawn;
    this.onError = onError;
    this.started = 0;
    this.drawnSeq = 0;
    this.decoding = 0;
    this.waiting = null;
    this.dropped = 0;
    /** null: frames are drawn once decoded; else called with each decoded frame, which is kept. */
    this.onHeld = null;
    /** Held decoded frames by id, oldest first: {frame, images}. */
    this.held = new Map();
    /** null: a decoded frame newer than the last drawn is drawn; else only where drawable(frame) is
     * true too (the viewer's video path may have painted a newer frame meanwhile). */
    this.drawable = null;
  }

  /** Keep decoded frames until present(frameId) (a wall cell); `onHeld(frame)` after each decode. */
  hold(onHeld) {
    this.onHeld = onHeld;
  }

  /**
   * Draw the held frame `frameId` (or the newest held one older than it, else the oldest held),
   * release it and every older one; returns the frame drawn, null when none is held.
   */
  present(frameId) {
    const ids = [...this.held.keys()];
    if (!ids.length) return null;
    const older = ids.filter((id) => id <= frameId);
    const chosen = older.length ? Math.max(...older) : Math.min(...ids);
    const { frame, images } = this.held.get(chosen);
    this.draw(frame, images);
    this.onDrawn(frame);
    for (const id of ids) {
      if (id <= chosen) {
        release(this.held.get(id).images);
        this.held.delete(id);
      }
    }
    return frame;
  }

  keep(frame, images) {
    if (this.held.has(frame.frameId)) release(this.held.get(frame.frameId).images);
    this.held.set(frame.frameId, { frame, images });
    while (this.held.size > MAX_HELD) {
      const [oldest] = this.held.keys();
      release(this.held.get(oldest).images);
      this.held.delete(oldest);
      this.dropped++;
    }
    this.onHeld(frame);
  }

  /** Queue a parsed frame (see protocol.parseFrame) for decoding and drawing. */
  submit(frame) {
    if (this.decoding >= MAX_DECODING) {
      if (this.waiting) this.dropped++;
      this.waiting = frame;
      return;
    }
    this.decode(frame, ++this.started);
  }

  async decode(frame, seq) {
    this.decoding++;
    const pending = frame.tiles.map(decodeTile);
    try {
      const images = await Promise.all(pending);
      if (this.onHeld && seq > this.drawnSeq) {
        this.drawnSeq = seq;
        this.keep(frame, images);
        return;
      }
      if (seq > this.drawnSeq && (!this.drawable || this.drawable(frame))) {
        this.draw(frame, images);
        this.drawnSeq = seq;
        this.onDrawn(frame);
      } else {
        this.dropped++;
      }
      release(images);
    } catch (error) {
      this.dropped++;
      Promise.allSettled(pending).then((results) =>
        release(results.map((r) => (r.status === "fulfilled" ? r.value : null))),
      );
      this.onError(error);
    } finally {
      this.decoding--;
      if (this.waiting && this.decoding < MAX_DECODING) {
        const next = this.waiting;
        this.waiting = null;
        this.submit(next);
      }
    }
  }

  draw(frame, images) {
    if (this.canvas.width !== frame.width || this.canvas.height !== frame.height) {
      this.canvas.width = frame.width;
      this.canvas.height = frame.height;
    }
    frame.tiles.forEach((tile, i) => {
      const image = images[i];
      if (image instanceof ImageData) {
        this.context.putImageData(image, tile.x, tile.y);
      } else {
        this.context.drawImage(image, tile.x, tile.y, tile.w, tile.h);
      }
    });
  }
}
