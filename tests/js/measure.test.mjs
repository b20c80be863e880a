// web/measure.js: clicks, frame pixels, projection, distances, angles, units, cuts and boxes.
import assert from "node:assert/strict";
import { test } from "node:test";

import {
  MAX_PLANES, angle, boxFrom, distance, formatLength, framePixel, isClick, project, unitsOf, withCut,
} from "../../web/measure.js";

const CAMERA = { eye: [0, 0, 10], target: [0, 0, 0], up: [0, 1, 0], fovy_deg: 90 };

test("a press that barely moves and is short is a click; a drag or a long press is not", () => {
  assert.equal(isClick({ x: 10, y: 10, t: 0 }, { x: 12, y: 13, t: 200 }), true);
  assert.equal(isClick({ x: 10, y: 10, t: 0 }, { x: 30, y: 10, t: 200 }), false);
  assert.equal(isClick({ x: 10, y: 10, t: 0 }, { x: 10, y: 10, t: 2000 }), false);
});

test("a point of the letterboxed element maps to the frame pixel under it", () => {
  // a 640x360 frame in a 320x400 box: scale 0.5, 110 px bands above and below
  assert.deepEqual(framePixel(0, 110, 320, 400, 640, 360), [0, 0]);
  assert.deepEqual(framePixel(319.9, 289.9, 320, 400, 640, 360), [639, 359]);
  assert.deepEqual(framePixel(160, 200, 320, 400, 640, 360), [320, 180]);
  assert.equal(framePixel(160, 50, 320, 400, 640, 360), null, "in the band above the picture");
});

test("projection puts the target at the centre and follows the field of view", () => {
  assert.deepEqual(project(CAMERA, 200, 100, [0, 0, 0]), [100, 50]);
  // fovy 90°: at depth 10 the top edge is y = 10; x spans aspect times as far
  const [x, y] = project(CAMERA, 200, 100, [20, 10, 0]);
  assert.ok(Math.abs(x - 200) < 1e-9 && Math.abs(y) < 1e-9);
  assert.equal(project(CAMERA, 200, 100, [0, 0, 20]), null, "behind the eye");
});

test("distances, angles and their units", () => {
  assert.equal(distance([0, 0, 0], [3, 4, 0]), 5);
  assert.ok(Math.abs(angle([1, 0, 0], [0, 0, 0], [0, 2, 0]) - 90) < 1e-9);
  assert.ok(Math.abs(angle([1, 0, 0], [0, 0, 0], [-1, 0, 0]) - 180) < 1e-9);
  assert.equal(angle([0, 0, 0], [0, 0, 0], [1, 0, 0]), 0);
  assert.equal(unitsOf("library/gltf_small/Duck.glb"), "m");
  assert.equal(unitsOf("upload/scan.ply"), "scene units");
  assert.equal(formatLength(0.153456, "m"), "0.1535 m");
  assert.equal(formatLength(12345678, "scene units"), "1.235e+7 scene units");
});

test("a cut keeps what lies behind the picked surface, at most six planes", () => {
  const clip = withCut({ box: null, cap: true }, [1, 2, 3], [0, 0, 1]);
  assert.deepEqual(clip, { box: null, cap: true, planes: [{ point: [1, 2, 3], normal: [-0, -0, -1] }] });
  let many = null;
  for (let i = 0; i < MAX_PLANES + 2; i++) many = withCut(many, [i, 0, 0], [1, 0, 0]);
  assert.equal(many.planes.length, MAX_PLANES);
  assert.deepEqual(many.planes.at(-1).point, [MAX_PLANES + 1, 0, 0], "the newest kept");
});

test("a section box from slider fractions of the bounds, none when empty", () => {
  const bounds = [[0, 0, 0], [10, 20, 40]];
  assert.deepEqual(boxFrom(bounds, { min: [0, 0.25, 0.5], max: [1, 0.75, 1] }), { min: [0, 5, 20], max: [10, 15, 40] });
  assert.equal(boxFrom(bounds, { min: [0.5, 0, 0], max: [0.5, 1, 1] }), null);
});
