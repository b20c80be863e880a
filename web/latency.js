// The viewer's own input → display latency: when each camera input (by sequence number) was sent,
// when the first frame answering it was drawn, summarised over a rolling window. No DOM, no
// clocks: the caller passes the times (ms, e.g. performance.now()).

/** Input sequence numbers run 1…MAX_INPUT_SEQ, then wrap to 1; 0 means "no input". */
export const MAX_INPUT_SEQ = 2 ** 32 - 1;
/** Latency samples and frame intervals the figures are computed over (the newest). */
export const WINDOW = 60;
/** Inputs awaiting an answer kept at most; beyond it the oldest are forgotten. */
export const MAX_PENDING = 256;
/** A longer pause between answering frames is idle time, not a frame interval (ms). */
export const IDLE_GAP_MS = 1000;

/** The sequence number after `seq`, wrapping past MAX_INPUT_SEQ to 1. */
export function nextSeq(seq) {
  return seq >= MAX_INPUT_SEQ ? 1 : seq + 1;
}

/** Whether sequence number `a` comes after `b`, across the wrap (serial number arithmetic). */
export function seqAfter(a, b) {
  return a !== b && ((a - b) >>> 0) < 2 ** 31;
}

/** The `q` (0…1) quantile of ascending `sorted`, interpolated linearly (as numpy.percentile). */
export function quantile(sorted, q) {
  const at = (sorted.length - 1) * q;
  const below = Math.floor(at);
  const above = Math.min(below + 1, sorted.length - 1);
  return sorted[below] + (sorted[above] - sorted[below]) * (at - below);
}

function pushWindowed(list, value) {
  if (list.push(value) > WINDOW) list.shift();
}

export class LatencyTracker {
  constructor() {
    this.pending = new Map(); // input seq → time sent, oldest first
    this.answered = null; // newest input seq a drawn frame answered
    this.lastAnswerAt = null;
    this.latencies = [];
    this.intervals = [];
    this.total = 0; // latency samples taken ever (the window keeps the newest WINDOW)
  }

  /** Camera input `seq` was sent at `now`. */
  sent(seq, now) {
    if (this.pending.has(seq)) return;
    this.pending.set(seq, now);
    if (this.pending.size > MAX_PENDING) this.pending.delete(this.pending.keys().next().value);
  }

  /**
   * A frame answering input `inputSeq` (and every input before it) is on screen at `now`.
   * Returns the latency of `inputSeq` in ms for the first frame answering it, else null (no
   * input, an input already answered — e.g. the still frame after motion — or one not sent here).
   * The time since the previous answering frame counts as a frame interval unless longer than
   * IDLE_GAP_MS; frames answering no new input (the still frame) count no interval.
   */
  drawn(inputSeq, now) {
    if (inputSeq === 0 || (this.answered !== null && !seqAfter(inputSeq, this.answered))) return null;
    this.answered = inputSeq;
    const sentAt = this.pending.get(inputSeq);
    for (const seq of this.pending.keys()) {
      if (seqAfter(seq, inputSeq)) break;
      this.pending.delete(seq);
    }
    if (this.lastAnswerAt !== null && now - this.lastAnswerAt <= IDLE_GAP_MS) {
      pushWindowed(this.intervals, now - this.lastAnswerAt);
    }
    this.lastAnswerAt = now;
    if (sentAt === undefined) return null;
    const latency = now - sentAt;
    pushWindowed(this.latencies, latency);
    this.total += 1;
    return latency;
  }

  /** {p50_ms, p90_ms, samples, interval_ms} over the window (interval_ms 0 until two answering
   * frames came close enough together), or null before the first sample. */
  summary() {
    if (!this.latencies.length) return null;
    const sorted = [...this.latencies].sort((a, b) => a - b);
    const interval = this.intervals.length ? this.intervals.reduce((a, b) => a + b, 0) / this.intervals.length : 0;
    return { p50_ms: quantile(sorted, 0.5), p90_ms: quantile(sorted, 0.9), samples: sorted.length, interval_ms: interval };
  }
}

/**
 * Camera input as a viewer sends it: the newest camera, at most one `camera` message per
 * `schedule` tick (an animation frame), each with the next input sequence number and its send
 * time (`now()`, ms) given to `tracker`. `send(message)` says whether the message went out.
 *
 * `window` ({inFlight, timeoutMs}; null: none): at most `inFlight` inputs sent and not yet
 * answered (the caller says `answered(seq)` when a frame answering `seq` comes; an input unanswered
 * for `timeoutMs` no longer counts); the newest camera waits meanwhile and goes out as soon as one
 * is answered. For a link where each message costs more than a frame's worth of pixels: the
 * notebook's comm, where every message is a kernel request whose busy and idle the page is told.
 * A camera that waits is timed from when it would have been sent without the window (the first
 * tick after it was set), so the latency counts the wait.
 */
export class CameraInput {
  constructor(send, tracker, schedule, now, window = null) {
    this.send = send;
    this.tracker = tracker;
    this.schedule = schedule;
    this.now = now;
    this.window = window;
    this.seq = 0;
    this.camera = null;
    /** A camera waits (for the next tick, or for the window): a camera the coordinator echoes meanwhile is older. */
    this.pending = false;
    /** Inputs sent and not answered yet, oldest first: [seq, time sent]. */
    this.unanswered = [];
    this.scheduled = false;
    this.changed = false;
    this.dueAt = null;
  }

  set(camera) {
    this.camera = camera;
    this.changed = true;
    this.pending = true;
    if (!this.scheduled) {
      this.scheduled = true;
      this.schedule(() => this.tick());
    }
  }

  /** A frame answering input `seq` (and every one before it) came: room in the window. */
  answered(seq) {
    while (this.unanswered.length && !seqAfter(this.unanswered[0][0], seq)) this.unanswered.shift();
    this.flush();
  }

  tick() {
    this.scheduled = false;
    this.flush();
    if (this.pending) {   // the window is full: look again next tick (an input may time out)
      this.scheduled = true;
      this.schedule(() => this.tick());
    }
  }

  flush() {
    if (!this.pending) return;
    const now = this.now();
    if (this.changed) {
      this.changed = false;
      this.dueAt = now;
    }
    if (this.window) {
      this.unanswered = this.unanswered.filter(([, at]) => now - at < this.window.timeoutMs);
      if (this.unanswered.length >= this.window.inFlight) return;
    }
    this.pending = false;
    const seq = nextSeq(this.seq);
    if (this.send({ type: "camera", camera: this.camera, seq })) {
      this.seq = seq;
      this.tracker.sent(seq, this.dueAt);
      if (this.window) this.unanswered.push([seq, now]);
    }
  }
}
