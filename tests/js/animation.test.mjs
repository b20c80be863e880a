// web/animation.js: the scene time label.
import assert from "node:assert/strict";
import { test } from "node:test";

import { AnimationControls, timeText } from "../../web/animation.js";

test("the scene time over the animation's end, one decimal", () => {
  assert.equal(timeText(12.345, 80), "12.3 s / 80.0 s");
  assert.equal(timeText(0, 1.25), "0.0 s / 1.3 s");
  assert.equal(timeText(Number.NaN, undefined), "– s / – s");
});

function fakeElement() {
  return { hidden: true, textContent: "", value: "0", min: "0", max: "0", dataset: {}, addEventListener() {} };
}

function fakeDocument() {
  const elements = new Map();
  return { getElementById: (id) => elements.get(id) ?? elements.set(id, fakeElement()).get(id) };
}

const ANIMATED = { playing: false, time: 2, speed: 1, start: 0, end: 80, animations: [{ name: "drive" }] };
const STATIC = { playing: false, time: 0, speed: 1, start: 0, end: 0, animations: [] };

test("the controls show for an animated scene and go, polling with them, when it has none", async () => {
  const doc = fakeDocument();
  let clock = ANIMATED;
  const api = async () => ({ ok: true, json: async () => clock });
  const controls = new AnimationControls(doc, api, () => {});
  await controls.load();
  assert.equal(doc.getElementById("animation").hidden, false);
  assert.equal(doc.getElementById("scene-time-text").textContent, "2.0 s / 80.0 s");
  assert.notEqual(controls.poller, null, "an animated scene's clock is polled");
  clock = STATIC;   // the coordinator came back with a static scene
  await controls.load();
  assert.equal(doc.getElementById("animation").hidden, true);
  assert.equal(controls.state, null);
  assert.equal(controls.poller, null, "no polling without animations");
});
