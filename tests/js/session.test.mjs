// web/session.js: which session a page shows, its socket path and its API paths.
import assert from "node:assert/strict";
import { test } from "node:test";

import {
  apiInit, frameSizeFor, sessionApiPath, sessionFromQuery, shortSceneName, steers, viewSocketPath, WATCH_HEADER,
} from "../../web/session.js";

test("a bare page shows the default session", () => {
  const session = sessionFromQuery("");
  assert.deepEqual(session, { key: null, watching: false, cell: null });
  assert.equal(viewSocketPath(session), "ws/view");
  assert.equal(sessionApiPath("api/stats", session), "api/stats");
});

test("a drive link reaches the session's own routes", () => {
  const session = sessionFromQuery("?session=a-b_c&token=x");
  assert.deepEqual(session, { key: "a-b_c", watching: false, cell: null });
  assert.equal(viewSocketPath(session), "ws/view?session=a-b_c");
  assert.equal(sessionApiPath("api/balancer", session), "api/sessions/a-b_c/balancer");
  assert.equal(sessionApiPath("web/x.js", session), "web/x.js");
});

test("a watch link reads its own session's routes with its watch key, named on every call", () => {
  const session = sessionFromQuery("?session=K&watch=1");
  assert.deepEqual(session, { key: "K", watching: true, cell: null });
  assert.equal(viewSocketPath(session), "ws/view?session=K&watch=1");
  assert.equal(sessionApiPath("api/stats", session), "api/sessions/K/stats");
  assert.deepEqual(apiInit({ method: "PUT", headers: { a: "b" } }, session),
    { method: "PUT", headers: { a: "b", [WATCH_HEADER]: "K" } });
  assert.deepEqual(apiInit(undefined, session), { headers: { [WATCH_HEADER]: "K" } });
  assert.equal(steers(session), false);
  const driver = sessionFromQuery("?session=D");
  assert.equal(apiInit(undefined, driver), undefined);
  assert.equal(steers(driver), true);
  assert.equal(steers(sessionFromQuery("?session=W&cell=0,0")), false);
});

test("scene names are shortened to their last part, cut in the middle when still long", () => {
  assert.equal(shortSceneName("library/gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"), "CesiumMilkTruck.gltf");
  assert.equal(shortSceneName("builtin:cluster"), "builtin:cluster");
  assert.equal(shortSceneName("upload/box.ply"), "box.ply");
  const long = shortSceneName(`upload/${"a".repeat(20)}_${"b".repeat(20)}.glb`, 21);
  assert.equal(long.length, 21);
  assert.equal(long, `${"a".repeat(10)}…${"b".repeat(6)}.glb`);
});

test("a wall cell's page names its cell on the socket", () => {
  const session = sessionFromQuery("?session=W&cell=1,0");
  assert.deepEqual(session, { key: "W", watching: false, cell: "1,0" });
  assert.equal(viewSocketPath(session), "ws/view?session=W&cell=1%2C0");
});

test("a driver asks for its canvas in device pixels, fitted to the largest size", () => {
  assert.deepEqual(frameSizeFor(800, 450, 2), [1600, 900]);
  assert.deepEqual(frameSizeFor(2560, 1440, 2, [3840, 2160]), [3840, 2160]);
  assert.deepEqual(frameSizeFor(1000, 100, 1, [500, 500]), [500, 50]);
  assert.deepEqual(frameSizeFor(4, 2, 1), [16, 16]);
  assert.equal(frameSizeFor(0, 300, 1), null);
});
