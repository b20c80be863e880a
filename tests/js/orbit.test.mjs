// web/orbit.js: camera navigation keeps its invariants (distance, up, never crossing the target).
import assert from "node:assert/strict";
import { test } from "node:test";

import {
  MIN_POLAR, basis, distance, dolly, frameBounds, orbit, pan, pinch, wheelFactor,
} from "../../web/orbit.js";

const CAMERA = { eye: [1, 2, 6], target: [0.5, 0.25, -1], up: [0, 1, 0], fovy_deg: 45 };
const sub = (a, b) => a.map((v, i) => v - b[i]);
const dot = (a, b) => a.reduce((sum, v, i) => sum + v * b[i], 0);
const norm = (a) => Math.hypot(...a);

function assertClose(actual, expected, tolerance = 1e-9, what = "value") {
  const a = [actual].flat();
  const e = [expected].flat();
  assert.equal(a.length, e.length, what);
  a.forEach((v, i) => assert.ok(Math.abs(v - e[i]) <= tolerance, `${what}[${i}]: ${v} != ${e[i]}`));
}

test("orbit keeps the distance to the target, the target and the up vector", () => {
  for (const [yaw, pitch] of [[0.3, 0.2], [-2.5, -0.7], [7, 0], [0, 3], [0, -3], [1, 1e-3]]) {
    const moved = orbit(CAMERA, yaw, pitch);
    assertClose(distance(moved), distance(CAMERA), 1e-9, `distance after orbit(${yaw}, ${pitch})`);
    assert.deepEqual(moved.target, CAMERA.target);
    assert.deepEqual(moved.up, CAMERA.up);
    assert.equal(moved.fovy_deg, CAMERA.fovy_deg);
  }
});

test("orbit moves the eye: yaw about up (right-handed), pitch toward up, clamped at the poles", () => {
  const front = { eye: [0, 0, 5], target: [0, 0, 0], up: [0, 1, 0], fovy_deg: 45 };
  assertClose(orbit(front, Math.PI / 2, 0).eye, [5, 0, 0], 1e-9, "yaw +90°");
  assertClose(orbit(front, 0, Math.PI / 4).eye, [0, 5 * Math.SQRT1_2, 5 * Math.SQRT1_2], 1e-9, "pitch +45°");
  const top = orbit(front, 0, 10);
  const polar = Math.acos(dot(sub(top.eye, top.target), [0, 1, 0]) / distance(top));
  assertClose(polar, MIN_POLAR, 1e-9, "polar angle at the pole");
  assert.ok(basis(top).right.every(Number.isFinite), "view direction stays off the up axis");
});

test("pan moves eye and target by the same vector, in the view plane", () => {
  const moved = pan(CAMERA, 30, -12, 360);
  const eyeShift = sub(moved.eye, CAMERA.eye);
  assertClose(eyeShift, sub(moved.target, CAMERA.target), 1e-12, "eye and target shifts");
  assert.ok(norm(eyeShift) > 0, "pan moved the camera");
  assertClose(dot(eyeShift, basis(CAMERA).forward), 0, 1e-12, "shift along the view direction");
  assertClose(distance(moved), distance(CAMERA), 1e-12, "distance");
});

test("pan by one image height moves the view by the visible height at the target", () => {
  const { right, up } = basis(CAMERA);
  const visible = 2 * distance(CAMERA) * Math.tan((45 * Math.PI) / 360);
  const down = sub(pan(CAMERA, 0, 400, 400).eye, CAMERA.eye);
  assertClose(down, up.map((v) => v * visible), 1e-9, "drag down moves the camera up");
  const right200 = sub(pan(CAMERA, 200, 0, 400).eye, CAMERA.eye);
  assertClose(right200, right.map((v) => -v * visible / 2), 1e-9, "drag right moves the camera left");
});

test("dolly scales the distance and never reaches or crosses the target", () => {
  assertClose(distance(dolly(CAMERA, 2, 1e-3)), 2 * distance(CAMERA), 1e-9, "zoom out ×2");
  const direction = sub(CAMERA.eye, CAMERA.target);
  let camera = CAMERA;
  for (let i = 0; i < 50; i++) camera = dolly(camera, wheelFactor(-1e6), 0.01);
  assertClose(distance(camera), 0.01, 1e-12, "distance stops at minDistance");
  assert.ok(dot(sub(camera.eye, camera.target), direction) > 0, "eye stays on its side of the target");
  assert.deepEqual(camera.target, CAMERA.target);
  assert.throws(() => dolly(CAMERA, 0, 0.01), RangeError);
  assert.throws(() => dolly(CAMERA, -1, 0.01), RangeError);
  assert.throws(() => dolly(CAMERA, Number.NaN, 0.01), RangeError);
});

test("wheel down zooms out, wheel up zooms in, always by a positive factor", () => {
  assert.ok(wheelFactor(100) > 1);
  assert.ok(wheelFactor(-100) < 1 && wheelFactor(-100) > 0);
  assert.equal(wheelFactor(0), 1);
  assert.ok(wheelFactor(3, 1) > wheelFactor(3, 0), "line-mode deltas count as more pixels");
  assert.ok(wheelFactor(-1e9) > 0);
});

test("pinch: spreading fingers zooms in, moving them together pans", () => {
  const before = [[100, 100], [200, 100]];
  const zoomed = pinch(CAMERA, before, [[50, 100], [250, 100]], 360, 1e-3);
  assertClose(distance(zoomed), distance(CAMERA) / 2, 1e-9, "spread ×2 halves the distance");
  assertClose(zoomed.target, CAMERA.target, 1e-9, "pure pinch keeps the target");
  const panned = pinch(CAMERA, before, [[110, 120], [210, 120]], 360, 1e-3);
  assertClose(distance(panned), distance(CAMERA), 1e-9, "two-finger pan keeps the distance");
  assertClose(panned.eye, pan(CAMERA, 10, 20, 360).eye, 1e-9, "two-finger pan = pan by the midpoint");
});

test("frameBounds matches tessera.geometry.default_camera", () => {
  // default_camera(np.array([[-1, 0, -2], [3, 2, 2]]), 50).to_json()
  const camera = frameBounds([[-1, 0, -2], [3, 2, 2]], 50);
  assertClose(camera.eye, [3.338006224319462, 3.338006224319462, 6.680017783769892], 1e-9, "eye");
  assertClose(camera.target, [1, 1, 0], 1e-12, "target");
  assert.deepEqual(camera.up, [0, 1, 0]);
  assert.equal(camera.fovy_deg, 50);
});
