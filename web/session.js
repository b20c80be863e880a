// Which session the page shows (issue 19): `?session=ID` drives session ID, `?session=KEY&watch=1`
// watches the session whose watch key is KEY (frames only), none: the default session;
// `&cell=COL,ROW` shows one cell of a display wall's session (issue 22; the coordinator checks it).

/**
 * @param {string} search  location.search
 * @returns {{key: string | null, watching: boolean, cell: string | null}}
 */
export function sessionFromQuery(search) {
  const params = new URLSearchParams(search);
  return { key: params.get("session"), watching: ["1", "true"].includes(params.get("watch") ?? ""),
    cell: params.get("cell") };
}

/**
 * The viewer socket's path for the session: `ws/view` with its query.
 * @param {{key: string | null, watching: boolean, cell?: string | null}} session
 */
export function viewSocketPath(session) {
  if (!session.key) return session.watching ? "ws/view?watch=1" : "ws/view";
  const query = new URLSearchParams({ session: session.key });
  if (session.watching) query.set("watch", "1");
  if (session.cell) query.set("cell", session.cell);
  return `ws/view?${query}`;
}

/**
 * An API path (`api/…`) for the session: a driven session's own routes are under
 * `api/sessions/ID/`; the default session's and a watcher's stay as they are (a watch key opens no
 * API route).
 * @param {string} path
 * @param {{key: string | null, watching: boolean}} session
 */
export function sessionApiPath(path, session) {
  if (!session.key || session.watching || !path.startsWith("api/")) return path;
  return `api/sessions/${encodeURIComponent(session.key)}/${path.slice(4)}`;
}

/**
 * The frame size a driving viewer asks for: its canvas's CSS size × devicePixelRatio, whole
 * pixels, scaled down (aspect kept) to fit `largest` and at least 16 a side; null while the canvas
 * has no size yet.
 * @param {number} cssWidth
 * @param {number} cssHeight
 * @param {number} dpr  window.devicePixelRatio
 * @param {[number, number]} largest  the coordinator's --max-size
 * @returns {[number, number] | null}
 */
export function frameSizeFor(cssWidth, cssHeight, dpr, largest = [3840, 2160]) {
  const width = cssWidth * (dpr || 1);
  const height = cssHeight * (dpr || 1);
  if (!(width >= 1 && height >= 1)) return null;
  const scale = Math.min(1, largest[0] / width, largest[1] / height);
  return [Math.max(16, Math.round(width * scale)), Math.max(16, Math.round(height * scale))];
}
