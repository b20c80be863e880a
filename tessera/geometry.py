"""Shared vocabulary: pixel rectangles, cameras and the camera matrices both sides use.

Pure: numpy only, no GL, no I/O. Matrices are float64, row-major (``M @ v`` for column
vectors); transpose before handing them to GL as column-major uniforms.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


class CameraError(ValueError):
    """A camera that cannot be rendered: NaN, degenerate or out of range."""


@dataclass(frozen=True, slots=True)
class Rect:
    """Integer pixel rectangle, origin top-left, ``w``×``h`` pixels."""

    x: int
    y: int
    w: int
    h: int

    @property
    def area(self) -> int:
        return self.w * self.h

    @property
    def x1(self) -> int:
        return self.x + self.w

    @property
    def y1(self) -> int:
        return self.y + self.h

    def as_list(self) -> list[int]:
        return [self.x, self.y, self.w, self.h]

    @classmethod
    def from_seq(cls, values: Sequence[Any]) -> Rect:
        if len(values) != 4 or not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            raise ValueError(f"a rect is four integers [x, y, w, h], got {values!r}")
        return cls(*values)

    def intersection_area(self, other: Rect) -> int:
        w = min(self.x1, other.x1) - max(self.x, other.x)
        h = min(self.y1, other.y1) - max(self.y, other.y)
        return max(w, 0) * max(h, 0)


def _vec3(value: Any, name: str) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise CameraError(f"camera {name} must be a list of 3 numbers, got {value!r}")
    return (_finite(value[0], name), _finite(value[1], name), _finite(value[2], name))


def _finite(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CameraError(f"camera {name} must be numbers, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise CameraError(f"camera {name} is not finite: {value!r}")
    return out


@dataclass(frozen=True, slots=True)
class Camera:
    """A pinhole camera: world-space eye, target, up; vertical field of view in degrees.

    ``near``/``far`` are optional; when absent they come from :func:`near_far_from_bounds`.
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fovy_deg: float = 45.0
    near: float | None = None
    far: float | None = None

    def __post_init__(self) -> None:
        for name in ("eye", "target", "up"):
            if not all(math.isfinite(v) for v in getattr(self, name)):
                raise CameraError(f"camera {name} is not finite: {getattr(self, name)!r}")
        for name in ("fovy_deg", "near", "far"):
            value = getattr(self, name)
            if value is not None and not math.isfinite(value):
                raise CameraError(f"camera {name} is not finite: {value!r}")
        # Plain floats, not numpy: a camera is made for each camera message (60 a second a viewer)
        # and each tile a node draws, and numpy's calls on 3-vectors cost 5x these.
        (ex, ey, ez), (tx, ty, tz), (ux, uy, uz) = self.eye, self.target, self.up
        fx, fy, fz = tx - ex, ty - ey, tz - ez
        distance = math.sqrt(fx * fx + fy * fy + fz * fz)
        scale = max(abs(ex), abs(ey), abs(ez), abs(tx), abs(ty), abs(tz), 1.0)
        if distance <= 1e-9 * scale:
            raise CameraError("camera eye and target coincide")
        up_norm = math.sqrt(ux * ux + uy * uy + uz * uz)
        if up_norm == 0.0:
            raise CameraError("camera up vector is zero")
        fx, fy, fz, ux, uy, uz = fx / distance, fy / distance, fz / distance, ux / up_norm, uy / up_norm, uz / up_norm
        cx, cy, cz = fy * uz - fz * uy, fz * ux - fx * uz, fx * uy - fy * ux
        if math.sqrt(cx * cx + cy * cy + cz * cz) < 1e-6:
            raise CameraError("camera up vector is parallel to the view direction")
        if not 0.5 <= self.fovy_deg <= 179.0:
            raise CameraError(f"camera fovy_deg must be in [0.5, 179], got {self.fovy_deg}")
        if self.near is not None and self.near <= 0.0:
            raise CameraError(f"camera near must be > 0, got {self.near}")
        if self.far is not None and self.far <= (self.near or 0.0):
            raise CameraError(f"camera far must be > near, got far={self.far} near={self.near}")

    @classmethod
    def from_json(cls, data: Any) -> Camera:
        """Parse and validate camera JSON (``eye``, ``target``, ``up``, ``fovy_deg``, ``near``, ``far``)."""
        if not isinstance(data, Mapping):
            raise CameraError(f"camera must be a JSON object, got {type(data).__name__}")
        unknown = set(data) - {"eye", "target", "up", "fovy_deg", "near", "far"}
        if unknown:
            raise CameraError(f"unknown camera fields: {sorted(unknown)}")
        for required in ("eye", "target"):
            if required not in data:
                raise CameraError(f"camera lacks {required!r}")
        near = data.get("near")
        far = data.get("far")
        return cls(
            eye=_vec3(data["eye"], "eye"),
            target=_vec3(data["target"], "target"),
            up=_vec3(data.get("up", [0.0, 1.0, 0.0]), "up"),
            fovy_deg=_finite(data.get("fovy_deg", 45.0), "fovy_deg"),
            near=None if near is None else _finite(near, "near"),
            far=None if far is None else _finite(far, "far"),
        )

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "eye": list(self.eye),
            "target": list(self.target),
            "up": list(self.up),
            "fovy_deg": self.fovy_deg,
        }
        if self.near is not None:
            out["near"] = self.near
        if self.far is not None:
            out["far"] = self.far
        return out


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float]) -> np.ndarray:
    """World→view matrix (4×4 float64), right-handed, camera looking down −Z. Scalar arithmetic on the
    three 3-vectors (a tile draws it twice: numpy's cross and norm cost 46 µs of it, this 6)."""
    ex, ey, ez = (float(v) for v in eye)
    tx, ty, tz = (float(v) for v in target)
    ux, uy, uz = (float(v) for v in up)
    fx, fy, fz = tx - ex, ty - ey, tz - ez
    length = math.sqrt(fx * fx + fy * fy + fz * fz)
    fx, fy, fz = fx / length, fy / length, fz / length
    sx, sy, sz = fy * uz - fz * uy, fz * ux - fx * uz, fx * uy - fy * ux
    length = math.sqrt(sx * sx + sy * sy + sz * sz)
    sx, sy, sz = sx / length, sy / length, sz / length
    vx, vy, vz = sy * fz - sz * fy, sz * fx - sx * fz, sx * fy - sy * fx
    return np.array([[sx, sy, sz, -(sx * ex + sy * ey + sz * ez)],
                     [vx, vy, vz, -(vx * ex + vy * ey + vz * ez)],
                     [-fx, -fy, -fz, fx * ex + fy * ey + fz * ez],
                     [0.0, 0.0, 0.0, 1.0]])


def perspective(fovy_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """View→clip matrix (4×4 float64), OpenGL conventions (NDC z in [−1, 1])."""
    f = 1.0 / math.tan(math.radians(fovy_deg) / 2.0)
    proj = np.zeros((4, 4))
    proj[0, 0] = f / aspect
    proj[1, 1] = f
    proj[2, 2] = (far + near) / (near - far)
    proj[2, 3] = 2.0 * far * near / (near - far)
    proj[3, 2] = -1.0
    return proj


def near_far_from_bounds(camera: Camera, bounds: np.ndarray) -> tuple[float, float]:
    """Clip distances for ``camera`` that enclose the scene's axis-aligned ``bounds`` (2×3).

    Camera values win where given. Derived from the bounding sphere so that every process
    computes the same numbers for the same camera and scene.
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    eye = np.asarray(camera.eye, dtype=np.float64)
    forward = np.asarray(camera.target, dtype=np.float64) - eye
    forward /= np.linalg.norm(forward)
    depth = float(np.dot(center - eye, forward))
    far = max(depth + radius * 1.01, radius * 0.02)
    if camera.far is not None:
        far = camera.far
    elif camera.near is not None and far <= camera.near:
        far = camera.near + 2.02 * radius
    near = max(depth - radius * 1.01, far * 1e-3)
    if camera.near is not None:
        near = camera.near
    elif near >= far:
        near = far * 1e-3
    return near, far


def view_projection(camera: Camera, size: tuple[int, int], bounds: np.ndarray) -> np.ndarray:
    """Full-frame world→clip matrix (4×4 float64) for a ``size`` = (width, height) image."""
    near, far = near_far_from_bounds(camera, bounds)
    width, height = size
    return perspective(camera.fovy_deg, width / height, near, far) @ look_at(camera.eye, camera.target, camera.up)


#: Default clear colour, linear RGB in [0, 1]; coordinator and ``--render-once`` share it.
DEFAULT_BACKGROUND = (0.11, 0.12, 0.15)


def default_camera(bounds: np.ndarray, fovy_deg: float = 45.0, aspect: float = 16 / 9) -> Camera:
    """A camera that frames the scene's axis-aligned ``bounds`` (2×3) from the front (+Z),
    slightly above, Y up, on an image of width/height ``aspect``."""
    lo, hi = np.asarray(bounds, dtype=np.float64)
    center = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 1e-6)
    half_fov = math.radians(fovy_deg) / 2.0
    narrowest = min(half_fov, math.atan(math.tan(half_fov) * aspect))
    distance = radius / math.sin(narrowest) * 1.05
    direction = np.array([0.35, 0.35, 1.0])
    direction /= np.linalg.norm(direction)
    eye = center + direction * distance
    return Camera(eye=tuple(eye.tolist()), target=tuple(center.tolist()), up=(0.0, 1.0, 0.0), fovy_deg=fovy_deg)
