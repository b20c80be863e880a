"""Camera paths for benchmarks, in the DESIGN.md format ``{"dt_ms": 33.3, "frames": [camera, …]}``.

``python -m bench.paths --scene PATH [--kinds orbit flythrough zoom] [--frames 60] [--dt-ms 33.3]
[--out-dir bench/paths] [--name NAME]`` writes ``NAME_KIND.json`` for each kind.

Kinds, for a scene's world ``bounds`` (2, 3):

- ``orbit``: one turn around the centre at the distance that frames the bounding sphere
  (as :func:`tessera.geometry.default_camera`), 19° above it, starting at the default view.
- ``flythrough``: the eye flies along a straight line from −x to +x, 0.6 bounding radii in front of
  the centre (grazing or crossing the model's surface), looking half ahead, half at the centre.
- ``zoom``: from the default view straight towards a ``focus`` point, ending at 1/8 of the
  starting distance, the target gliding from the centre to the focus (eased at both ends). The
  command line focuses on the scene's vertex nearest the default eye: a surface point in view.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from tessera.geometry import Camera, default_camera

KINDS = ("orbit", "flythrough", "zoom")
DEFAULT_FRAMES = 60
DEFAULT_DT_MS = 33.3
ELEVATION_RAD = math.atan2(0.35, math.hypot(0.35, 1.0))   # default_camera's direction (0.35, 0.35, 1)
ZOOM_END = 1.0 / 8.0


def _ease(t: np.ndarray) -> np.ndarray:
    """Smoothstep 0…1 → 0…1 with zero speed at both ends."""
    return t * t * (3.0 - 2.0 * t)


def _camera(eye: np.ndarray, target: np.ndarray) -> dict[str, Any]:
    camera = Camera(eye=tuple(np.round(eye, 6).tolist()), target=tuple(np.round(target, 6).tolist()), fovy_deg=45.0)
    return camera.to_json()


def make_path(kind: str, bounds: np.ndarray, frames: int = DEFAULT_FRAMES, dt_ms: float = DEFAULT_DT_MS,
              focus: np.ndarray | None = None) -> dict[str, Any]:
    """A camera path of ``kind`` (:data:`KINDS`) with ``frames`` cameras ``dt_ms`` apart around the
    scene ``bounds`` (2, 3); ``focus`` (3,) is the zoom's end point (default: the centre)."""
    if kind not in KINDS:
        raise ValueError(f"unknown path kind {kind!r}; choose from {', '.join(KINDS)}")
    if frames < 2 or not dt_ms > 0.0:
        raise ValueError(f"need at least 2 frames and dt_ms > 0, got {frames} and {dt_ms}")
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    start = default_camera(np.stack([lo, hi]))
    start_eye = np.asarray(start.eye)
    distance = float(np.linalg.norm(start_eye - center))
    t = np.linspace(0.0, 1.0, frames)
    cameras = []
    if kind == "orbit":
        yaw0 = math.atan2(0.35, 1.0)
        for angle in yaw0 + 2.0 * math.pi * t * (frames - 1) / frames:  # the last frame stops short of the first
            direction = np.array([math.sin(angle) * math.cos(ELEVATION_RAD), math.sin(ELEVATION_RAD),
                                  math.cos(angle) * math.cos(ELEVATION_RAD)])
            cameras.append(_camera(center + direction * distance, center))
    elif kind == "flythrough":
        for s in t:
            eye = center + radius * np.array([3.2 * s - 1.6, 0.15, 0.6])
            inward = (center - eye) / np.linalg.norm(center - eye)
            ahead = 0.5 * np.array([1.0, 0.0, 0.0]) + inward
            cameras.append(_camera(eye, eye + radius * ahead / np.linalg.norm(ahead)))
    else:
        point = center if focus is None else np.asarray(focus, dtype=np.float64)
        for s in _ease(t):
            eye = point + (start_eye - point) * (1.0 - s * (1.0 - ZOOM_END))
            cameras.append(_camera(eye, center + (point - center) * s))
    return {"dt_ms": dt_ms, "frames": cameras}


#: Random cameras (:func:`random_cameras`): elevation range (degrees above the horizontal plane
#: through the target), distance as a multiple of the distance that frames the bounding sphere, the
#: target's offset from the centre in bounding radii, and the vertical field of view (degrees).
RANDOM_ELEVATION_DEG = (-30.0, 75.0)
RANDOM_DISTANCE = (0.55, 1.6)
RANDOM_TARGET_OFFSET = 0.3
RANDOM_FOVY_DEG = (30.0, 60.0)


def random_cameras(bounds: np.ndarray, count: int, seed: int = 0, aspect: float = 16 / 9) -> list[Camera]:
    """``count`` cameras around the scene ``bounds`` (2, 3), drawn from ``seed`` (the same seed, the
    same cameras): the eye at a uniformly random azimuth, an elevation in
    :data:`RANDOM_ELEVATION_DEG` (uniform in its sine: even over that band of the sphere), at
    :data:`RANDOM_DISTANCE` × the distance that frames the bounding sphere at its field of view and
    ``aspect`` (log-uniform: as many near as far; never inside the bounding sphere), looking at a point up to
    :data:`RANDOM_TARGET_OFFSET` bounding radii from the centre, Y up, a field of view in
    :data:`RANDOM_FOVY_DEG`. Near and far are left to the scene bounds, as everywhere."""
    if count < 0:
        raise ValueError(f"count must be >= 0, got {count}")
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    low, high = (math.sin(math.radians(e)) for e in RANDOM_ELEVATION_DEG)
    cameras = []
    for _ in range(count):
        fovy = float(rng.uniform(*RANDOM_FOVY_DEG))
        half_fov = math.radians(fovy) / 2.0
        framing = radius / math.sin(min(half_fov, math.atan(math.tan(half_fov) * aspect)))
        distance = framing * math.exp(rng.uniform(*np.log(RANDOM_DISTANCE)))
        offset = rng.normal(size=3)
        offset *= RANDOM_TARGET_OFFSET * radius * float(rng.uniform()) ** (1 / 3) / max(np.linalg.norm(offset), 1e-12)
        distance = max(distance, 1.1 * radius + float(np.linalg.norm(offset)))   # the eye outside the bounding sphere
        azimuth = float(rng.uniform(0.0, 2.0 * math.pi))
        rise = float(rng.uniform(low, high))
        flat = math.sqrt(1.0 - rise * rise)
        direction = np.array([math.sin(azimuth) * flat, rise, math.cos(azimuth) * flat])
        target = center + offset
        camera = Camera(eye=tuple(np.round(target + direction * distance, 6).tolist()),
                        target=tuple(np.round(target, 6).tolist()), fovy_deg=round(fovy, 3))
        cameras.append(camera)
    return cameras


def orbit_around(camera: Camera, frames: int = DEFAULT_FRAMES, dt_ms: float = DEFAULT_DT_MS) -> dict[str, Any]:
    """A camera path of one turn of ``camera``'s eye around its target about the vertical (Y)
    axis, at its height and distance, its field of view kept: ``frames`` cameras ``dt_ms`` apart,
    the first ``camera`` itself (a random camera moving as ``orbit`` moves the default one)."""
    eye, target = np.asarray(camera.eye, dtype=np.float64), np.asarray(camera.target, dtype=np.float64)
    offset = eye - target
    cameras = []
    for angle in 2.0 * math.pi * np.arange(frames) / frames:
        c, s = math.cos(angle), math.sin(angle)
        turned = np.array([c * offset[0] + s * offset[2], offset[1], -s * offset[0] + c * offset[2]])
        cameras.append(Camera(eye=tuple(np.round(target + turned, 6).tolist()), target=camera.target,
                              fovy_deg=camera.fovy_deg).to_json())
    return {"dt_ms": dt_ms, "frames": cameras}


def surface_focus(positions: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """(3,) the vertex of ``positions`` (N, 3) nearest the default camera's eye for ``bounds``."""
    eye = np.asarray(default_camera(bounds).eye)
    return np.asarray(positions[int(np.argmin(np.linalg.norm(positions - eye, axis=1)))], dtype=np.float64)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.paths", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", required=True, help="scene file or builtin:NAME")
    parser.add_argument("--kinds", nargs="+", choices=KINDS, default=list(KINDS))
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES)
    parser.add_argument("--dt-ms", type=float, default=DEFAULT_DT_MS)
    parser.add_argument("--out-dir", type=Path, default=Path(__file__).resolve().parent / "paths")
    parser.add_argument("--name", help="file name prefix (default: the scene file's stem)")
    args = parser.parse_args(argv)
    from node.scene.loading import load_scene

    scene = load_scene(args.scene, face_limit=1 << 62)
    positions = np.concatenate([b.positions for b in scene.batches]).astype(np.float64)
    name = args.name or Path(args.scene.removeprefix("builtin:")).stem
    args.out_dir.mkdir(parents=True, exist_ok=True)
    for kind in args.kinds:
        path = make_path(kind, scene.bounds, args.frames, args.dt_ms, surface_focus(positions, scene.bounds))
        out = args.out_dir / f"{name}_{kind}.json"
        out.write_text(json.dumps(path, separators=(",", ":")) + "\n")
        print(f"wrote {out} ({len(path['frames'])} frames, {out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
