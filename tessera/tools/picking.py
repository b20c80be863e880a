"""Picking (issue 35): which surface a pixel's centre sees, where, and facing which way.

A node draws an id pass of the one pixel (:mod:`node.gl.id_pass`: the frame's camera, scene state and
clip, with a projection narrowed to that pixel by :func:`window_matrix`), reads which triangle
covers its centre, and this module turns that triangle into the answer, in float64: the point is
where the pixel centre's ray (:func:`pixel_ray`) meets the triangle's plane (exact to the
triangle, not to the 24-bit depth buffer), the normal is the triangle's, turned to face the eye,
and ``depth`` is the point's distance from the eye in scene units. A pixel that sees the cap of a
cut (the inside of a cut surface drawn in the cap colour) answers the point where its ray enters
what the clip keeps, on the cutting plane, with that plane's normal (:func:`cap_entry`). In
sort-last each node answers for its share, and the nearest answer wins (:func:`nearest`).

Pure: numpy only.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tessera.geometry import Camera, Rect, view_projection


@dataclass(frozen=True, slots=True)
class PickHit:
    """What a pixel's centre sees: ``object`` (its name), ``primitive`` (the triangle's number among
    the object's triangles as the scene was loaded), the world ``point`` and unit ``normal``
    (facing the eye) and ``depth``, the point's distance from the eye (scene units)."""

    object: str
    primitive: int
    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    depth: float

    def to_json(self) -> dict[str, Any]:
        return {"hit": True, "object": self.object, "primitive": self.primitive, "point": list(self.point),
                "normal": list(self.normal), "depth": self.depth}


def window_matrix(window: Rect, size: tuple[int, int]) -> np.ndarray:
    """(4, 4) float64 clip-space matrix that maps the ``window`` pixels of a ``size`` = (w, h)
    frame onto a whole viewport of the window's size, applied after the frame's projection: a
    window-sized framebuffer then holds that part of the frame, each pixel centre where the frame's
    is (x right, y down, as :class:`Rect`)."""
    width, height = size
    matrix = np.identity(4)
    matrix[0, 0] = width / window.w
    matrix[0, 3] = (width - 2.0 * window.x) / window.w - 1.0
    matrix[1, 1] = height / window.h
    matrix[1, 3] = 1.0 - (height - 2.0 * window.y) / window.h
    return matrix


def pixel_ray(camera: Camera, size: tuple[int, int], bounds: np.ndarray, x: int,
              y: int) -> tuple[np.ndarray, np.ndarray]:
    """The eye (3,) and the unit direction (3,) float64 of the ray through the centre of pixel
    (``x``, ``y``) (from the top left) of a ``size`` frame drawn with ``camera`` over scene
    ``bounds`` (the near/far planes the frame has)."""
    width, height = size
    ndc_x = 2.0 * (x + 0.5) / width - 1.0
    ndc_y = 1.0 - 2.0 * (y + 0.5) / height
    inverse = np.linalg.inv(view_projection(camera, size, bounds))
    near, far = (inverse @ np.array([ndc_x, ndc_y, z, 1.0]) for z in (-1.0, 1.0))
    direction = far[:3] / far[3] - near[:3] / near[3]
    return np.asarray(camera.eye, dtype=np.float64), direction / np.linalg.norm(direction)


def triangle_hit(origin: np.ndarray, direction: np.ndarray, corners: np.ndarray) -> tuple[float, np.ndarray] | None:
    """Where the ray meets the plane of the triangle ``corners`` (3, 3): its distance along the ray
    and the triangle's unit normal turned to face the ray's origin; None for a degenerate triangle
    or one the ray runs along."""
    corners = np.asarray(corners, dtype=np.float64)
    normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
    length = float(np.linalg.norm(normal))
    slope = float(np.dot(normal, direction))
    if not length > 0.0 or abs(slope) <= 1e-12 * length:
        return None
    distance = float(np.dot(normal, corners[0] - origin)) / slope
    normal = normal / length
    return distance, normal if np.dot(normal, direction) < 0.0 else -normal


def cap_entry(origin: np.ndarray, direction: np.ndarray, halfspaces: np.ndarray) -> tuple[float, int] | None:
    """Where the ray enters what every one of ``halfspaces`` (P, 4) keeps (a·x + b·y + c·z + d ≥ 0):
    its distance along the ray and the row of the half-space it enters last; None when the ray
    starts inside them all."""
    planes = np.asarray(halfspaces, dtype=np.float64).reshape(-1, 4)
    start = planes[:, :3] @ origin + planes[:, 3]
    slope = planes[:, :3] @ direction
    entering = (start < 0.0) & (slope > 0.0)
    if not entering.any():
        return None
    distances = np.where(entering, -start / np.where(entering, slope, 1.0), -np.inf)
    row = int(np.argmax(distances))
    return float(distances[row]), row


def nearest(answers: Iterable[PickHit | None]) -> PickHit | None:
    """The nearest of several nodes' answers (sort-last: each for its share); None: none hit."""
    hits = [answer for answer in answers if answer is not None]
    return min(hits, key=lambda hit: hit.depth, default=None)
