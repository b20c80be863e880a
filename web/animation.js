// Animation controls (issue 11), shown only when the scene has animations: play/pause and a time
// slider over the span the animation loops, backed by GET/PUT /api/animation. While shown, the
// clock is polled ~2×/s so the slider follows a playing animation (not while it is dragged).

const POLL_MS = 500;

/** "12.3 s / 80.0 s": the scene time over the animation's end. */
export function timeText(time, end) {
  const fixed = (value) => (Number.isFinite(value) ? value.toFixed(1) : "–");
  return `${fixed(time)} s / ${fixed(end)} s`;
}

export class AnimationControls {
  /**
   * @param {Document} doc  holds #animation, #play, #scene-time and #scene-time-text
   * @param {(path: string, init?: object) => Promise<Response>} api  fetch with the viewer's token
   * @param {(message: string) => void} report  shows a failure ("" clears it)
   * @param {boolean} steering  whether this page may play, pause and jump (a watch page shows the clock only)
   */
  constructor(doc, api, report, steering = true) {
    this.api = api;
    this.report = report;
    this.section = doc.getElementById("animation");
    this.button = doc.getElementById("play");
    this.slider = doc.getElementById("scene-time");
    this.text = doc.getElementById("scene-time-text");
    this.clock = null;
    this.dragging = false;
    this.poller = null;
    if (!steering) return;
    this.button.addEventListener("click", () => this.put({ playing: !this.clock?.playing }));
    this.slider.addEventListener("input", () => {
      this.dragging = true;
      this.text.textContent = timeText(Number(this.slider.value), this.clock?.end);
    });
    this.slider.addEventListener("change", () => {
      this.dragging = false;
      this.put({ time: Number(this.slider.value) });
    });
  }

  /** The animation clock as last read ({playing, time, speed, start, end, animations}), or null. */
  get state() {
    return this.clock;
  }

  /** Read the clock; the controls appear when the scene has animations (call when the scene is known). */
  async load() {
    try {
      const response = await this.api("api/animation");
      if (!response.ok) return;
      this.show(await response.json());
    } catch (error) {
      this.report(`animation unavailable (${error.message})`);
    }
    if (this.clock && this.poller === null) this.poller = setInterval(() => this.load(), POLL_MS);
  }

  show(clock) {
    if (!clock.animations || clock.animations.length === 0) {
      this.hide();
      return;
    }
    this.clock = clock;
    this.section.hidden = false;
    this.button.textContent = clock.playing ? "pause" : "play";
    this.button.dataset.playing = String(clock.playing);
    this.slider.min = String(clock.start);
    this.slider.max = String(clock.end);
    if (!this.dragging) {
      this.slider.value = String(clock.time);
      this.text.textContent = timeText(clock.time, clock.end);
    }
  }

  /** No animations (a coordinator restarted with a static scene): no controls, no polling. */
  hide() {
    this.clock = null;
    this.section.hidden = true;
    clearInterval(this.poller);
    this.poller = null;
  }

  async put(body) {
    this.report("");
    try {
      const response = await this.api("api/animation", {
        method: "PUT",
        headers: { "Content-Type": "application/json" },
        body: JSON.stringify(body),
      });
      if (!response.ok) throw new Error(`${response.status} ${(await response.text()).slice(0, 200)}`);
    } catch (error) {
      this.report(`animation: ${error.message}`);
    }
    await this.load();
  }
}
