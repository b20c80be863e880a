// Mouse, wheel and touch input on the frame: pointer gestures become orbit.js camera moves.
// Left drag orbits; right/middle drag or Shift/Ctrl + left drag pans; the wheel zooms.
// Touch: one finger orbits, two fingers pinch-zoom and pan.

import { orbit, pan, dolly, pinch, wheelFactor } from "./orbit.js";

/** Orbit rate: a drag across the full image height turns the view by π. */
const ORBIT_RADIANS_PER_HEIGHT = Math.PI;
/** After the last wheel tick the user still counts as interacting for this long (ms). */
const WHEEL_SETTLE_MS = 250;

export class Controls {
  /**
   * @param {HTMLElement} element  receives pointer and wheel events
   * @param {{camera: () => object|null, setCamera: (camera: object) => void,
   *   viewHeight: () => number, minDistance: () => number}} view
   *   viewHeight: CSS pixel height of the displayed image (letterboxing excluded)
   */
  constructor(element, view) {
    this.view = view;
    this.pointers = new Map();
    this.lastWheel = -Infinity;
    element.style.touchAction = "none";
    element.addEventListener("pointerdown", (e) => this.down(e, element));
    element.addEventListener("pointermove", (e) => this.move(e));
    for (const type of ["pointerup", "pointercancel", "lostpointercapture"]) {
      element.addEventListener(type, (e) => this.pointers.delete(e.pointerId));
    }
    element.addEventListener("wheel", (e) => this.wheel(e), { passive: false });
    element.addEventListener("contextmenu", (e) => e.preventDefault());
  }

  /** True while a pointer is down or a wheel gesture is in progress: remote cameras wait. */
  get interacting() {
    return this.pointers.size > 0 || performance.now() - this.lastWheel < WHEEL_SETTLE_MS;
  }

  down(event, element) {
    if (!this.view.camera()) return;
    element.setPointerCapture(event.pointerId);
    const panning = event.button === 1 || event.button === 2 || event.shiftKey || event.ctrlKey;
    this.pointers.set(event.pointerId, { x: event.clientX, y: event.clientY, panning });
    event.preventDefault();
  }

  move(event) {
    const pointer = this.pointers.get(event.pointerId);
    const camera = this.view.camera();
    if (!pointer || !camera || this.pointers.size > 2) return;
    const height = this.view.viewHeight();
    if (this.pointers.size === 2) {
      const [a, b] = [...this.pointers.values()];
      const before = [[a.x, a.y], [b.x, b.y]];
      pointer.x = event.clientX;
      pointer.y = event.clientY;
      const after = [[a.x, a.y], [b.x, b.y]];
      this.view.setCamera(pinch(camera, before, after, height, this.view.minDistance()));
      return;
    }
    const dx = event.clientX - pointer.x;
    const dy = event.clientY - pointer.y;
    pointer.x = event.clientX;
    pointer.y = event.clientY;
    if (dx === 0 && dy === 0) return;
    if (pointer.panning) {
      this.view.setCamera(pan(camera, dx, dy, height));
    } else {
      const perPixel = ORBIT_RADIANS_PER_HEIGHT / height;
      this.view.setCamera(orbit(camera, -dx * perPixel, dy * perPixel));
    }
  }

  wheel(event) {
    const camera = this.view.camera();
    if (!camera) return;
    event.preventDefault();
    this.lastWheel = performance.now();
    this.view.setCamera(dolly(camera, wheelFactor(event.deltaY, event.deltaMode), this.view.minDistance()));
  }
}
