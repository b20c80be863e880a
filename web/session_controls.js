// Session controls in the panel (issue 19): the session this page shows (its scene, shortened with
// the full name on hover, and its size), a new session of a library scene, the session's drive
// and watch links, and a scene file dropped on the page uploaded and opened as a new session. The
// panel offers what the coordinator allows (issue 38, GET /api/library): the picker says how to add
// scenes when the library has none, the drop hint says how to turn uploads on when they are off,
// and a watch page offers nothing that changes anything (its watch link only). Backed by
// GET /api/library, GET /api/scenes, POST /api/scenes, POST /api/sessions, GET /api/sessions/{key}.

import { shortSceneName, steers, WATCH_HEADER } from "./session.js";

/** The session line: whose session, its scene (short), its size. */
export function sessionLine(session, scene, size) {
  const whose = session.watching ? "watching" : session.key ? "your session" : "the shared session";
  const parts = [whose, scene && shortSceneName(scene), size && size.join("×")].filter(Boolean);
  return parts.join(" · ") + (session.watching ? " (this link cannot steer)" : "");
}

/** The drop hint: how big a file may be dropped, or why not and how to turn uploads on. */
export function uploadHint(library) {
  if (!library.uploads) return library.uploads_off;
  const formats = library.formats.map((format) => format.toUpperCase()).join(", ");
  return `or drop a scene file (${formats}; up to ${library.max_upload_mb} MiB) on the picture`;
}

export class SessionControls {
  /**
   * @param {Document} doc
   * @param {(path: string, init?: object) => Promise<Response>} fetchApi  fetch of a coordinator path
   * @param {{key: string | null, watching: boolean, cell: string | null}} session  the session this page shows
   * @param {import("./messages.js").Messages} messages  what the user is told
   * @param {(url: string) => void} open  goes to a viewer page
   */
  constructor(doc, fetchApi, session, messages, open) {
    this.doc = doc;
    this.fetchApi = fetchApi;
    this.session = session;
    this.messages = messages;
    this.open = open;
    this.steering = steers(session);
    /** GET /api/library, once read. */
    this.library = null;
    this.scene = null;
    this.size = null;
    /** Whether the user has chosen a scene in the picker. */
    this.picked = false;
  }

  $(id) {
    return this.doc.getElementById(id);
  }

  async start() {
    if (this.steering) this.$("new-session").addEventListener("click", () => this.create(this.$("scene-pick").value));
    // Once the user picks a scene, the session's own scene no longer takes the picker back.
    this.$("scene-pick").addEventListener("change", () => { this.picked = true; });
    const target = this.doc.body;
    // A file dropped anywhere would make the browser leave the page for it: the page takes every drop.
    target.addEventListener("dragover", (event) => event.preventDefault());
    target.addEventListener("drop", (event) => {
      event.preventDefault();
      const file = event.dataTransfer?.files?.[0];
      if (!file) return;
      if (this.steering) this.upload(file);
      else this.messages.say("this page watches a session: it opens no scene (a drive link or the shared page does)");
    });
    if (!this.steering) return this.showLinks();
    await Promise.all([this.loadLibrary(), this.showLinks()]);
    await this.loadScenes();
  }

  async loadLibrary() {
    const response = await this.fetchApi("api/library");
    if (!response.ok) return;
    this.library = await response.json();
    const hint = this.$("library-hint");
    hint.textContent = this.library.library_hint ?? "";
    hint.hidden = !this.library.library_hint;
    this.$("upload-hint").textContent = uploadHint(this.library);
  }

  async loadScenes() {
    const response = await this.fetchApi("api/scenes");
    if (!response.ok) return;
    const pick = this.$("scene-pick");
    pick.replaceChildren(...(await response.json()).map((scene) => {
      const option = this.doc.createElement("option");
      option.value = scene.name;
      option.title = scene.name;
      return option;
    }));
    this.showScene();
  }

  /** Each stats poll: the session's scene (its size comes from the picture: {@link showPicture}). */
  showStats(stats) {
    if (stats.scene && stats.scene !== this.scene) {
      this.scene = stats.scene;
      this.showScene();
    }
  }

  /** The frame on the picture is `width`×`height`. */
  showPicture(width, height) {
    if (this.size && this.size[0] === width && this.size[1] === height) return;
    this.size = [width, height];
    this.showScene();
  }

  /** The session line, and the picker: the session's scene chosen and marked "shown now". */
  showScene() {
    const line = this.$("session-name");
    line.textContent = sessionLine(this.session, this.scene, this.size);
    line.title = this.scene ? `scene: ${this.scene}` : "";
    const pick = this.$("scene-pick");
    for (const option of pick.options) {
      const current = option.value === this.scene;
      option.textContent = shortSceneName(option.value) + (current ? " · shown now" : "");
      if (current && !this.picked && this.doc.activeElement !== pick) pick.value = option.value;
    }
  }

  async showLinks() {
    const { key, watching } = this.session;
    if (!key) return;
    const headers = watching ? { [WATCH_HEADER]: key } : {};
    const response = await this.fetchApi(`api/sessions/${encodeURIComponent(key)}`, { headers });
    if (!response.ok) return;   // a session that does not exist: the page says so (viewer.js)
    const info = await response.json();
    if (info.viewer_url) this.$("drive-link").value = info.viewer_url;
    this.$("watch-link").value = info.watch_url;
    this.$("session-links").hidden = false;
  }

  /** Open a new session of library scene `scene` and go to it. */
  async create(scene) {
    this.messages.clear();
    if (!scene) return;
    const response = await this.fetchApi("api/sessions", {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify({ scene }),
    });
    const body = await response.json().catch(() => ({}));
    if (!response.ok) {
      this.messages.say(`no new session: ${body.detail ?? response.status}`);
      return;
    }
    this.open(body.viewer_url);
  }

  /** Upload a dropped scene file, then open it as a new session. */
  async upload(file) {
    this.messages.clear();
    if (this.library && !this.library.uploads) {
      this.messages.say(`${file.name} not uploaded: ${this.library.uploads_off}`);
      return;
    }
    this.messages.say(`uploading ${file.name}…`, "info");
    const form = new FormData();
    form.append("file", file, file.name);
    const response = await this.fetchApi("api/scenes", { method: "POST", body: form });
    const body = await response.json().catch(() => ({}));
    if (!response.ok) {
      this.messages.say(`${file.name} refused: ${body.detail ?? response.status}`);
      return;
    }
    await this.create(body.name);
  }
}
