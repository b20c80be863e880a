// The viewer's WebSocket to the coordinator, reconnecting by itself with exponential back-off;
// a session that does not exist (any more) ends it: no retries.

export const FIRST_RETRY_MS = 500;
/** The coordinator's close code for a session that does not exist (closed, or a wrong link). */
export const CLOSE_NO_SESSION = 4404;
export const MAX_RETRY_MS = 8000;

/** Wait before reconnect attempt `attempt` (0, 1, …): doubling from FIRST_RETRY_MS, capped. */
export function retryDelay(attempt) {
  return Math.min(MAX_RETRY_MS, FIRST_RETRY_MS * 2 ** Math.min(attempt, 16));
}

export class Connection {
  /**
   * @param {string} url  ws:// or wss:// address of /ws/view
   * @param {{onText: (msg: object) => void, onBinary: (buf: ArrayBuffer) => void,
   *   onState: (state: {state: string, detail: string}) => void}} handlers
   *   state is "connecting", "open", "closed" (detail says why and when the next try is) or "gone"
   *   (the session does not exist: no more tries; detail is the coordinator's reason)
   */
  constructor(url, handlers) {
    this.url = url;
    this.handlers = handlers;
    this.socket = null;
    this.attempt = 0;
  }

  get open() {
    return this.socket !== null && this.socket.readyState === WebSocket.OPEN;
  }

  start() {
    this.handlers.onState({ state: "connecting", detail: "" });
    const socket = new WebSocket(this.url);
    socket.binaryType = "arraybuffer";
    this.socket = socket;
    socket.onopen = () => this.handlers.onState({ state: "open", detail: "" });
    socket.onmessage = (event) => {
      this.attempt = 0; // reset on a message, not on open: a rejected token opens, then closes
      if (typeof event.data === "string") {
        this.handlers.onText(JSON.parse(event.data));
      } else {
        this.handlers.onBinary(event.data);
      }
    };
    socket.onclose = (event) => {
      if (event.code === CLOSE_NO_SESSION) {
        this.handlers.onState({ state: "gone", detail: event.reason });
        return;
      }
      const delay = retryDelay(this.attempt++);
      const reason = event.code === 4401 ? "wrong token · " : event.reason ? `${event.reason} · ` : "";
      this.handlers.onState({ state: "closed", detail: `${reason}retry in ${(delay / 1000).toFixed(1)} s` });
      setTimeout(() => this.start(), delay);
    };
  }

  /** Send a JSON message if connected; returns whether it was sent. */
  send(message) {
    if (!this.open) return false;
    this.socket.send(JSON.stringify(message));
    return true;
  }
}
