// Session controls in the panel (issue 19): a new session of a library scene, the current
// session's drive and watch links, and a scene file dropped on the page uploaded and opened as a
// new session. Backed by GET /api/scenes, POST /api/scenes, POST /api/sessions, GET /api/sessions/{id}.

export class SessionControls {
  /**
   * @param {Document} doc
   * @param {(path: string, init?: object) => Promise<Response>} fetchApi  fetch of a coordinator path
   * @param {{key: string | null, watching: boolean}} session  the session this page shows
   * @param {(text: string) => void} say  shows a message to the user
   * @param {(url: string) => void} open  goes to a viewer page
   */
  constructor(doc, fetchApi, session, say, open) {
    this.doc = doc;
    this.fetchApi = fetchApi;
    this.session = session;
    this.say = say;
    this.open = open;
  }

  async start() {
    const $ = (id) => this.doc.getElementById(id);
    $("new-session").addEventListener("click", () => this.create($("scene-pick").value));
    const target = this.doc.body;
    target.addEventListener("dragover", (event) => event.preventDefault());
    target.addEventListener("drop", (event) => {
      event.preventDefault();
      const file = event.dataTransfer?.files?.[0];
      if (file) this.upload(file);
    });
    await Promise.all([this.loadScenes(), this.showLinks()]);
  }

  async loadScenes() {
    const response = await this.fetchApi("api/scenes");
    if (!response.ok) return;
    const pick = this.doc.getElementById("scene-pick");
    pick.replaceChildren(...(await response.json()).map((scene) => {
      const option = this.doc.createElement("option");
      option.value = option.textContent = scene.name;
      return option;
    }));
  }

  async showLinks() {
    const { key, watching } = this.session;
    const $ = (id) => this.doc.getElementById(id);
    if (watching) {
      $("session-name").textContent = "watching a session (this link cannot steer)";
      return;
    }
    if (!key) return;
    const response = await this.fetchApi(`api/sessions/${encodeURIComponent(key)}`);
    if (!response.ok) {
      this.say("this session is closed or the link is wrong");
      return;
    }
    const info = await response.json();
    $("session-name").textContent = `${info.scene} · ${info.size.join("×")}`;
    $("drive-link").value = info.viewer_url;
    $("watch-link").value = info.watch_url;
    $("session-links").hidden = false;
  }

  /** Open a new session of library scene `scene` and go to it. */
  async create(scene) {
    if (!scene) return;
    const response = await this.fetchApi("api/sessions", {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify({ scene }),
    });
    const body = await response.json().catch(() => ({}));
    if (!response.ok) {
      this.say(`no new session: ${body.detail ?? response.status}`);
      return;
    }
    this.open(body.viewer_url);
  }

  /** Upload a dropped scene file, then open it as a new session. */
  async upload(file) {
    this.say(`uploading ${file.name}…`);
    const form = new FormData();
    form.append("file", file, file.name);
    const response = await this.fetchApi("api/scenes", { method: "POST", body: form });
    const body = await response.json().catch(() => ({}));
    if (!response.ok) {
      this.say(`${file.name} refused: ${body.detail ?? response.status}`);
      return;
    }
    await this.create(body.name);
  }
}
