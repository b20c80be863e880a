// Camera navigation as pure functions: camera JSON in, new camera JSON out.
// Conventions as tessera/geometry.py look_at: right-handed, the camera looks down −Z, so
// forward = target − eye, right = forward × up, screen-up = right × forward.
// Cameras are {eye: [x,y,z], target: [x,y,z], up: [x,y,z], fovy_deg}; lengths in scene units,
// angles in radians unless named _deg, pointer movements in CSS pixels.

/** Closest the view direction may come to ±up (radians), so look_at stays well defined. */
export const MIN_POLAR = 0.01;

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const length = (a) => Math.hypot(a[0], a[1], a[2]);
const normalize = (a) => scale(a, 1 / length(a));

/** Only the fields the viewer sends; near/far are left to the coordinator (derived from bounds). */
function camera(eye, target, base) {
  return { eye, target, up: [...base.up], fovy_deg: base.fovy_deg };
}

/** Some unit vector perpendicular to unit vector `v`. */
function perpendicular(v) {
  const axis = Math.abs(v[0]) < 0.9 ? [1, 0, 0] : [0, 1, 0];
  return normalize(cross(v, axis));
}

/** Distance from eye to target. */
export function distance(cam) {
  return length(sub(cam.eye, cam.target));
}

/** Camera basis: unit right, screen-up and forward vectors. */
export function basis(cam) {
  const forward = normalize(sub(cam.target, cam.eye));
  const right = normalize(cross(forward, cam.up));
  return { right, up: cross(right, forward), forward };
}

/**
 * Turn the eye around the target: `yaw` about the camera's up vector (right-handed), `pitch`
 * raising the eye toward up. Distance to the target and the up vector are kept; the polar
 * angle is clamped to [MIN_POLAR, π − MIN_POLAR].
 */
export function orbit(cam, yaw, pitch) {
  const up = normalize(cam.up);
  const offset = sub(cam.eye, cam.target);
  const radius = length(offset);
  const polar = Math.acos(Math.min(1, Math.max(-1, dot(offset, up) / radius)));
  const horizontal = sub(offset, scale(up, dot(offset, up)));
  const h = length(horizontal) > 1e-12 * radius ? normalize(horizontal) : perpendicular(up);
  const turned = add(scale(h, Math.cos(yaw)), scale(cross(up, h), Math.sin(yaw)));
  const newPolar = Math.min(Math.PI - MIN_POLAR, Math.max(MIN_POLAR, polar - pitch));
  const newOffset = add(scale(turned, radius * Math.sin(newPolar)), scale(up, radius * Math.cos(newPolar)));
  return camera(add(cam.target, newOffset), [...cam.target], cam);
}

/**
 * Move the eye along the view ray: distance becomes distance × `factor` (> 0), never less than
 * `minDistance`, so the eye never reaches or crosses the target.
 */
export function dolly(cam, factor, minDistance) {
  if (!(factor > 0) || !Number.isFinite(factor)) {
    throw new RangeError(`dolly factor must be a positive number, got ${factor}`);
  }
  const offset = sub(cam.eye, cam.target);
  const current = length(offset);
  const wanted = Math.max(current * factor, minDistance);
  return camera(add(cam.target, scale(offset, wanted / current)), [...cam.target], cam);
}

/** Dolly factor for a wheel event: scrolling down (deltaY > 0) zooms out. */
export function wheelFactor(deltaY, deltaMode = 0) {
  const pixels = deltaY * (deltaMode === 1 ? 16 : deltaMode === 2 ? 400 : 1);
  return Math.exp(Math.max(-500, Math.min(500, pixels)) * 0.0015);
}

/**
 * Slide eye and target together in the view plane so the scene at the target's depth follows
 * the pointer: (dx, dy) CSS pixels on an image `viewHeight` CSS pixels tall (y down).
 */
export function pan(cam, dx, dy, viewHeight) {
  const { right, up } = basis(cam);
  const unitsPerPixel = (2 * distance(cam) * Math.tan((cam.fovy_deg * Math.PI) / 360)) / viewHeight;
  const shift = add(scale(right, -dx * unitsPerPixel), scale(up, dy * unitsPerPixel));
  return camera(add(cam.eye, shift), add(cam.target, shift), cam);
}

/**
 * Two-finger gesture between two touch positions `before` and `after` ([[x, y], [x, y]] CSS
 * pixels): spreading the fingers zooms in, moving their midpoint pans.
 */
export function pinch(cam, before, after, viewHeight, minDistance) {
  const spread = (p) => Math.hypot(p[1][0] - p[0][0], p[1][1] - p[0][1]);
  const mid = (p) => [(p[0][0] + p[1][0]) / 2, (p[0][1] + p[1][1]) / 2];
  const factor = spread(after) > 0 && spread(before) > 0 ? spread(before) / spread(after) : 1;
  const zoomed = dolly(cam, factor, minDistance);
  const [x0, y0] = mid(before);
  const [x1, y1] = mid(after);
  return pan(zoomed, x1 - x0, y1 - y0, viewHeight);
}

/** Camera framing axis-aligned `bounds` [[x,y,z],[x,y,z]], as tessera.geometry.default_camera. */
export function frameBounds(bounds, fovyDeg = 45) {
  const [lo, hi] = bounds;
  const center = scale(add(lo, hi), 0.5);
  const radius = Math.max(length(sub(hi, lo)) / 2, 1e-6);
  const away = (radius / Math.sin((fovyDeg * Math.PI) / 360)) * 1.05;
  const eye = add(center, scale(normalize([0.35, 0.35, 1.0]), away));
  return { eye, target: center, up: [0, 1, 0], fovy_deg: fovyDeg };
}

/** Smallest eye–target distance the viewer allows: a small fraction of the scene's size. */
export function minDistanceFor(bounds) {
  return bounds ? Math.max(length(sub(bounds[1], bounds[0])) * 1e-3, 1e-6) : 1e-3;
}
