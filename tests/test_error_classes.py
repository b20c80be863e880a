"""bench.error_classes (issue 32): view-space points from window depth, the facing of a tilted plane,
depth steps, each pixel's class and each class's share of a frame's squared error. No GL."""

from __future__ import annotations

import math

import numpy as np

from bench.error_classes import CLASSES, classify, depth_steps, error_shares, facing, view_positions

NEAR, FAR, FOVY = 0.5, 20.0, 60.0


def window_depth(z: np.ndarray) -> np.ndarray:
    """The window depth of view depths ``z`` under the test's projection."""
    ndc = (FAR + NEAR - 2.0 * NEAR * FAR / z) / (FAR - NEAR)
    return (ndc + 1.0) / 2.0


def test_view_positions_undo_the_projection():
    z = np.full((9, 16), 3.0)
    points = view_positions(window_depth(z), NEAR, FAR, FOVY)
    assert np.allclose(points[..., 2], -3.0)
    half = math.tan(math.radians(FOVY) / 2.0)
    assert np.isclose(points[0, 0, 1], 3.0 * half * (1.0 - 1.0 / 9.0))      # row 0 at the top
    assert np.isclose(points[0, 0, 0], -3.0 * half * 16 / 9 * (1.0 - 1.0 / 16.0))
    assert np.isclose(view_positions(np.zeros((1, 1)), NEAR, FAR, FOVY)[0, 0, 2], -NEAR)


def test_facing_of_a_plane_turned_sixty_degrees_from_the_eye():
    h, w = 33, 33
    half = math.tan(math.radians(FOVY) / 2.0)
    rays = np.stack(np.meshgrid(((np.arange(w) + 0.5) / w * 2 - 1) * half,
                                (1 - (np.arange(h) + 0.5) / h * 2) * half), axis=-1)
    rays = np.concatenate([rays, -np.ones((h, w, 1))], axis=-1)
    normal = np.array([math.sin(math.radians(60)), 0.0, math.cos(math.radians(60))])
    through = np.array([0.0, 0.0, -4.0])
    points = rays * ((through @ normal) / (rays @ normal))[..., None]
    cos = facing(points)
    centre = points[h // 2, w // 2]
    expected = abs(centre @ normal) / np.linalg.norm(centre)
    assert np.isclose(cos[h // 2, w // 2], expected, atol=1e-6) and np.isclose(expected, 0.5, atol=0.02)
    flat = np.concatenate([rays[..., :2] * 2.0, np.full((h, w, 1), -2.0)], axis=-1)
    assert np.isclose(facing(flat)[h // 2, w // 2], 1.0)


def test_depth_steps_mark_both_sides_of_a_step_only():
    z = np.ones((4, 8))
    z[:, 4:] = 1.5
    z[:, :4] += np.arange(4) * 0.001      # a slope under the relative jump is no step
    steps = depth_steps(z, np.ones(z.shape, bool))
    assert steps[:, 3].all() and steps[:, 4].all() and steps.sum() == 8


def test_classes_and_error_shares_of_a_square_before_a_wall():
    h, w = 40, 60
    z = np.full((h, w), np.inf)
    z[5:35, 5:55] = 4.0                       # a wall facing the eye, background around it
    z[15:25, 20:40] = 2.0                     # a box in front of it
    depth = np.where(np.isinf(z), 1.0, window_depth(np.where(np.isinf(z), 1.0, z)))
    empty = np.isinf(z)
    classes = classify(depth, empty, empty, NEAR, FAR, FOVY)
    assert (classes[empty] == -1).all()
    assert classes[5, 30] == CLASSES.index("outline") and classes[8, 30] == CLASSES.index("facing")
    assert classes[15, 30] == CLASSES.index("depth_edge") and classes[13, 30] == CLASSES.index("depth_edge")
    assert classes[20, 30] == CLASSES.index("facing")
    reference = np.zeros((h, w, 3), np.uint8)
    frame = reference.copy()
    frame[15, 30] = 10                        # error on a depth step only
    frame[1, 1] = 255                         # and on the background, which no class holds
    shares = error_shares(frame, reference, classes)
    assert shares["depth_edge"]["error"] == round(300 / (300 + 3 * 255 ** 2), 3)
    assert shares["facing"]["error"] == 0.0
    assert math.isclose(sum(shares[name]["pixels"] for name in CLASSES), float((~empty).mean()), abs_tol=1e-3)
    assert shares["model_db"] == round(10 * math.log10(255 ** 2 / (300 / 3 / 1500)), 2)   # the wall's 1500 pixels
    assert shares["mean"] == round(30 / (3 * 1500), 2)
