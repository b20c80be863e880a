"""Screen footprints of world boxes (DPBP input): contain every projected corner, clip, behind-eye."""

from __future__ import annotations

import tracemalloc

import numpy as np

from tessera.balancers.projection import BOX_BLOCK, project_boxes, project_groups
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


def test_many_boxes_project_in_bounded_memory_as_one_by_one():
    """A sort-last node projects every chunk of its share in view (147k for a third of the 24.8M-
    triangle model): the corners' temporaries are a block's, not all boxes' at once (112 MB there,
    a fifth of the node's peak), and the rects are those of each box alone."""
    rng = np.random.default_rng(5)
    count = 12 * BOX_BLOCK + 17
    lo = rng.uniform(-3, 2, (count, 3))
    boxes = np.concatenate([lo, lo + rng.uniform(0.01, 1.0, (count, 3))], axis=1).astype(np.float32)
    camera = Camera(eye=(3.0, 2.0, 6.0), target=(0.0, 0.0, 0.0))
    tracemalloc.start()
    try:
        rects = project_boxes(boxes, camera, SIZE, BOUNDS)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    all_at_once = count * 8 * 4 * 8    # the (K, 8, 4) float64 clip coordinates alone
    assert peak < 0.5 * all_at_once, f"{peak / 2**20:.1f} MB for {count} boxes"
    picked = rng.choice(count, 40, replace=False)
    for index in picked:
        assert np.array_equal(rects[index], project_boxes(boxes[index], camera, SIZE, BOUNDS)[0])
