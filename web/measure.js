// The viewer's tools as pure functions (issue 35): where a click lands in the frame, when a
// pointer gesture is a click (or a tap), where a world point shows on screen, distances, angles
// and the units they are in, and the clip planes and section box the tools ask for.
// Cameras are camera JSON ({eye, target, up, fovy_deg}); points [x, y, z] in scene units.

import { basis } from "./orbit.js";
import { fitFrame } from "./overlay.js";

/** A pointer that moved less than this (CSS px) between down and up clicked (or tapped). */
export const CLICK_SLOP_PX = 5;
/** A press longer than this (ms) is no click. */
export const CLICK_MS = 600;
/** The planes a session may have (the section box comes on top). */
export const MAX_PLANES = 6;

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const length = (a) => Math.hypot(a[0], a[1], a[2]);

/** Whether a press from `down` {x, y, t} to `up` {x, y, t} (CSS px, ms) is a click or a tap. */
export function isClick(down, up) {
  return Math.hypot(up.x - down.x, up.y - down.y) < CLICK_SLOP_PX && up.t - down.t < CLICK_MS;
}

/**
 * The frame pixel [x, y] (integers, from the top left) under a point `offsetX`, `offsetY` (CSS px
 * from the element's top left) of an element `boxW`×`boxH` showing a `width`×`height` frame
 * letterboxed; null outside the picture.
 */
export function framePixel(offsetX, offsetY, boxW, boxH, width, height) {
  const fit = fitFrame(width, height, boxW, boxH);
  const x = Math.floor((offsetX - fit.x) / fit.scale);
  const y = Math.floor((offsetY - fit.y) / fit.scale);
  return x >= 0 && y >= 0 && x < width && y < height ? [x, y] : null;
}

/**
 * Where world `point` shows in a `width`×`height` frame of `camera`: [x, y] in frame pixels from the
 * top left (fractional), or null behind the eye.
 */
export function project(camera, width, height, point) {
  const { right, up, forward } = basis(camera);
  const offset = sub(point, camera.eye);
  const depth = dot(offset, forward);
  if (!(depth > 1e-9)) return null;
  const half = Math.tan((camera.fovy_deg * Math.PI) / 360);
  const ndcX = dot(offset, right) / (depth * half * (width / height));
  const ndcY = dot(offset, up) / (depth * half);
  return [((ndcX + 1) / 2) * width, ((1 - ndcY) / 2) * height];
}

/** Distance between two points (scene units). */
export function distance(a, b) {
  return length(sub(a, b));
}

/** The angle at `vertex` between the rays to `a` and `b`, in degrees (0 for a degenerate one). */
export function angle(a, vertex, b) {
  const u = sub(a, vertex);
  const v = sub(b, vertex);
  const lengths = length(u) * length(v);
  if (!(lengths > 0)) return 0;
  return (Math.acos(Math.min(1, Math.max(-1, dot(u, v) / lengths))) * 180) / Math.PI;
}

/** The unit a scene's coordinates are in: glTF's are metres, other formats say nothing. */
export function unitsOf(sceneName) {
  return /\.(glb|gltf)$/i.test(sceneName ?? "") ? "m" : "scene units";
}

/** A length as the overlay labels it: 4 significant digits and the units. */
export function formatLength(value, units) {
  const text = Math.abs(value) >= 1e5 || (Math.abs(value) < 1e-3 && value !== 0) ? value.toExponential(3)
    : Number(value.toPrecision(4)).toString();
  return `${text} ${units}`;
}

/**
 * The session's clip state (PUT …/clip) with one more plane through a picked `point` cutting away
 * what lies on the side its `normal` faces (the eye's side: the cut shows what is behind the
 * surface), the oldest dropped beyond MAX_PLANES.
 */
export function withCut(clip, point, normal) {
  const planes = [...(clip?.planes ?? []), { point, normal: normal.map((v) => -v) }];
  return { ...(clip ?? {}), planes: planes.slice(-MAX_PLANES) };
}

/**
 * The section box a slider position gives: `fractions` {min: [fx, fy, fz], max: [...]} in 0…1 of
 * the scene `bounds` [[x0, y0, z0], [x1, y1, z1]]; null when it would be empty on an axis.
 */
export function boxFrom(bounds, fractions) {
  const [lo, hi] = bounds;
  const min = [0, 1, 2].map((axis) => lo[axis] + fractions.min[axis] * (hi[axis] - lo[axis]));
  const max = [0, 1, 2].map((axis) => lo[axis] + fractions.max[axis] * (hi[axis] - lo[axis]));
  return min.every((value, axis) => value < max[axis]) ? { min, max } : null;
}
