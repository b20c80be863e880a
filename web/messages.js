// What the panel tells the user (issue 38). A message (a refusal, an error, "uploading…") stays until
// the user dismisses it or does the next thing (`clear`, called by every action); a passing status
// ("stats unavailable" while the coordinator restarts) has a line of its own and goes by itself.

export class Messages {
  /** @param {Document} doc  holds #panel-message (with #panel-message-text, #dismiss-message) and #panel-status */
  constructor(doc) {
    this.box = doc.getElementById("panel-message");
    this.text = doc.getElementById("panel-message-text");
    this.statusLine = doc.getElementById("panel-status");
    doc.getElementById("dismiss-message").addEventListener("click", () => this.clear());
  }

  /** Show `text` until dismissed or the next action; `kind` "error" (default) or "info". */
  say(text, kind = "error") {
    this.text.textContent = text;
    this.box.dataset.kind = kind;
    this.box.hidden = false;
  }

  /** The user did the next thing (or dismissed the message): it goes. */
  clear() {
    this.box.hidden = true;
    this.text.textContent = "";
  }

  /** The passing status line ("" hides it). */
  status(text) {
    this.statusLine.textContent = text;
    this.statusLine.hidden = !text;
  }
}
