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
 * An API path (`api/…`) for the session: a session's own routes are under `api/sessions/KEY/` (its
 * id, or for a watcher its watch key, which reads them and changes nothing); the default session's
 * are `api/…` as they are.
 * @param {string} path
 * @param {{key: string | null, watching: boolean}} session
 */
export function sessionApiPath(path, session) {
  if (!session.key || !path.startsWith("api/")) return path;
  return `api/sessions/${encodeURIComponent(session.key)}/${path.slice(4)}`;
}

/** The header a watch page names its watch key in, on every API call (the coordinator refuses any
 * change made with one). */
export const WATCH_HEADER = "X-Tessera-Watch";

/**
 * `fetch` options for an API call of this page: a watcher's carry its watch key in WATCH_HEADER.
 * @param {object | undefined} init
 * @param {{key: string | null, watching: boolean}} session
 */
export function apiInit(init, session) {
  if (!session.watching || !session.key) return init;
  return { ...init, headers: { ...(init?.headers ?? {}), [WATCH_HEADER]: session.key } };
}

/** Whether this page may change its session: not a watch link, not a wall's cell. */
export function steers(session) {
  return !session.watching && !session.cell;
}

/**
 * A scene name short enough for the panel: its last path part (`library/cars/truck.glb` →
 * `truck.glb`; `builtin:cluster` as it is), cut in the middle with "…" beyond `max` characters.
 * The full name goes in the element's title.
 * @param {string} name
 * @param {number} max
 */
export function shortSceneName(name, max = 30) {
  const last = String(name).split("/").filter(Boolean).pop() ?? String(name);
  if (last.length <= max) return last;
  const head = Math.ceil((max - 1) / 2);
  return `${last.slice(0, head)}…${last.slice(last.length - (max - 1 - head))}`;
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
