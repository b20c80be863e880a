// web/animation.js: the scene time label.
import assert from "node:assert/strict";
import { test } from "node:test";

import { timeText } from "../../web/animation.js";

test("the scene time over the animation's end, one decimal", () => {
  assert.equal(timeText(12.345, 80), "12.3 s / 80.0 s");
  assert.equal(timeText(0, 1.25), "0.0 s / 1.3 s");
  assert.equal(timeText(Number.NaN, undefined), "– s / – s");
});
