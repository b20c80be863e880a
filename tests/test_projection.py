"""Screen footprints of world boxes (DPBP input): contain every projected corner, clip, behind-eye."""

from __future__ import annotations

import numpy as np

from tessera.balancers.projection import project_boxes, project_groups
from tessera.geometry import Camera, view_projection

BOUNDS = np.array([[-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]])
SIZE = (640, 480)


def _pixel(camera: Camera, point: np.ndarray) -> np.ndarray:
    clip = view_projection(camera, SIZE, BOUNDS) @ np.append(point, 1.0)
    ndc = clip[:2] / clip[3]
    return np.array([(ndc[0] * 0.5 + 0.5) * SIZE[0], (0.5 - ndc[1] * 0.5) * SIZE[1]])


def test_footprint_contains_points_inside_the_box():
    rng = np.random.default_rng(3)
    camera = Camera(eye=(3.0, 2.0, 6.0), target=(0.0, 0.0, 0.0))
    for _ in range(50):
        lo = rng.uniform(-2, 1.5, 3)
        box = np.concatenate([lo, lo + rng.uniform(0.05, 0.5, 3)])
        rect = project_boxes(box[None], camera, SIZE, BOUNDS)[0]
        for point in rng.uniform(box[:3], box[3:], size=(20, 3)):
            x, y = np.clip(_pixel(camera, point), 0, SIZE)
            assert rect[0] - 1e-6 <= x <= rect[2] + 1e-6 and rect[1] - 1e-6 <= y <= rect[3] + 1e-6


def test_behind_straddling_and_offscreen_boxes():
    camera = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0))
    boxes = np.array([
        [-1, -1, 10, 1, 1, 11],     # behind the eye
        [-1, -1, 4, 1, 1, 6],       # around the eye
        [50, 50, 0, 51, 51, 1],     # far off to the side
        [-0.1, -0.1, -0.1, 0.1, 0.1, 0.1],
    ], dtype=float)
    rects = project_boxes(boxes, camera, SIZE, BOUNDS)
    assert rects[0].tolist() == [0, 0, 0, 0]
    assert rects[1].tolist() == [0, 0, 640, 480]
    assert rects[2].tolist() == [0, 0, 0, 0]
    assert 300 < rects[3][0] < 320 < rects[3][2] < 340
    groups = project_groups(boxes, np.array([1, 2, 3, 4]), camera, SIZE, BOUNDS)
    assert groups.weights.tolist() == [2.0, 4.0]
    assert groups.boxes.shape == (2, 4)
