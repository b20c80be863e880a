"""The pixels a world-space error spans on screen (tessera/screen_error.py), the levels-of-detail
bound a node's level choice and the balancers' predictions share (issue 32): every segment inside a
box, projected with the frame's real matrix, is at most its length times the box's error scale;
the scale is ``s / d`` on the view axis and grows with the box; a group off the axis in the corner of
a wide frame, whose error projects past the bound there though ``error · s / d`` (the bound before)
fits it, is drawn finer, by the nodes and in the balancers' predictions alike."""

from __future__ import annotations

import numpy as np
import pytest

from node.culling.lod import lod_cut, projected_errors
from node.scene.lod import LodTree
from tessera.balancers.projection import GroupProjector, distinct_level_boxes, level_counts, project_groups
from tessera.geometry import Camera, view_projection
from tessera.screen_error import error_scales, pixels_per_unit
from tests.culling_support import random_cameras

BOUNDS = np.array([[-4.0, -4.0, -4.0], [4.0, 4.0, 4.0]])


def pixels(camera: Camera, size: tuple[int, int], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixel positions of world ``points`` (N, 3) through the frame's real matrix, and (N,)
    whether each is inside the frame's frustum (on screen, in front of the eye)."""
    clip = np.c_[points, np.ones(len(points))] @ view_projection(camera, size, BOUNDS).T
    w = clip[:, 3]
    ndc = clip[:, :2] / np.where(w > 0.0, w, 1.0)[:, None]
    seen = (w > 0.0) & np.all(np.abs(ndc) <= 1.0, axis=1)
    return np.c_[(ndc[:, 0] + 1.0) / 2.0 * size[0], (1.0 - ndc[:, 1]) / 2.0 * size[1]], seen


def test_no_segment_inside_a_box_spans_more_pixels_than_its_length_times_the_scale():
    rng = np.random.default_rng(11)
    spans = 0
    for camera in random_cameras(BOUNDS / 2.0, 40, seed=4, nearest=0.1, widest_deg=150.0):
        size = (int(rng.integers(64, 2000)), int(rng.integers(64, 2000)))
        lo = rng.uniform(-3.0, 3.0, size=(500, 3))
        boxes = np.stack([lo, lo + rng.uniform(0.001, 1.5, size=(500, 3)) ** 2], axis=1)
        a, b = (rng.uniform(boxes[:, 0], boxes[:, 1]) for _ in range(2))
        (pa, seen_a), (pb, seen_b) = pixels(camera, size, a), pixels(camera, size, b)
        seen = seen_a & seen_b   # the frustum is convex: the whole segment is on screen
        span = np.linalg.norm(pa - pb, axis=1)[seen]
        bound = np.linalg.norm(a - b, axis=1)[seen] * error_scales(camera, size, boxes[seen])
        assert np.all(span <= bound * (1.0 + 1e-9) + 1e-9), float((span / bound).max())
        spans += int(seen.sum())
    assert spans > 5000


def test_the_scale_is_s_over_d_on_the_view_axis_and_grows_with_the_box():
    camera = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), fovy_deg=50.0)
    size = (1280, 720)
    on_axis = np.array([[[-1e-6, -1e-6, 0.0], [1e-6, 1e-6, 1.0]]])
    assert error_scales(camera, size, on_axis)[0] == pytest.approx(pixels_per_unit(camera, size) / 4.0, rel=1e-9)
    rng = np.random.default_rng(2)
    lo = rng.uniform(-3.0, 3.0, size=(300, 3))
    inner = np.stack([lo, lo + rng.uniform(0.0, 1.0, size=(300, 3))], axis=1)
    outer = inner + np.stack([-rng.uniform(0.0, 1.0, size=(300, 3)), rng.uniform(0.0, 1.0, size=(300, 3))], axis=1)
    assert np.all(error_scales(camera, size, outer) >= error_scales(camera, size, inner))
    assert np.isinf(error_scales(camera, size, np.array([[[-1.0, -1.0, 4.0], [1.0, 1.0, 6.0]]]))[0]), \
        "the eye inside a box: never coarse there"


def one_group(box: np.ndarray, error: float) -> LodTree:
    """A model of one leaf (chunk 0) simplified once by one group of ``error`` over ``box`` (2, 3)
    into one coarse cluster of one triangle."""
    ints = lambda *v: np.array(v, np.int64)   # noqa: E731
    empty = ints()
    return LodTree(leaf_first_chunk=ints(0), leaf_end_chunk=ints(1), leaf_group=ints(0), group_level=ints(1),
                   group_error=np.array([error], np.float32), group_boxes=box[None].astype(np.float32),
                   batch=ints(0), own=ints(0), parent=ints(-1), boxes=box[None].astype(np.float32),
                   index_bounds=ints(0, 3), indices=np.arange(3, dtype=np.uint32), cluster_parts=ints(0, 1),
                   part_bounds=ints(0, 3), part_boxes=box[None].astype(np.float32), share_cluster=empty,
                   share_chunk=empty, share_triangles=empty, batch_closed=np.zeros(1, bool))


def test_a_group_off_the_axis_in_a_wide_frame_gets_a_finer_level():
    """Eye at the origin looking down −z, 120° vertical field, 16:9: a group near the frame's corner
    whose error, along the direction the view stretches most there, projects to 4× the bound, while
    ``error · s / d`` fits it (before, the node drew its coarse level and the balancers counted it)."""
    camera = Camera(eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), fovy_deg=120.0)
    size, bound = (1280, 720), 1.0
    slope = np.array([0.9 * np.tan(np.radians(60.0)) * 16 / 9, 0.9 * np.tan(np.radians(60.0))])
    p = np.array([*(3.0 * slope), -3.0])                         # depth 3, near the corner
    stretch = np.array([*slope, slope @ slope])                  # view space (x, y, −z): the direction
    stretch /= np.linalg.norm(stretch)                           # the projection stretches most at p
    scale = pixels_per_unit(camera, size)
    error = 0.9 * bound * np.linalg.norm(p) / scale              # as s / d at p: 0.9 px
    q = p + error * stretch
    (pp, qq), seen = pixels(camera, size, np.stack([p, q]))
    assert seen.all()
    true_px = float(np.linalg.norm(pp - qq))
    assert true_px > 4.0 * bound, true_px
    box = np.stack([np.minimum(p, q), np.maximum(p, q)])
    assert error * scale / np.linalg.norm(np.clip(0.0, box[0], box[1])) <= bound, "the bound before fits it"

    tree = one_group(box, error)
    assert projected_errors(tree, camera, size)[0] >= true_px
    cut = lod_cut(tree, camera, size, bound)
    assert not cut.coarse and cut.blocked_first.size == 0, "drawn at full detail"
    far = lod_cut(tree, camera, size, 20.0 * bound)
    assert far.coarse, "a looser bound draws it coarse"
    errors, triangles = np.array([[0.0, error]]), np.array([[100.0, 1.0]])
    boxes = np.stack([box.reshape(6)] * 2)[None]
    assert level_counts(errors, triangles, boxes, camera, size, bound)[0] == 100.0, "predicted at full detail"
    assert level_counts(errors, triangles, boxes, camera, size, 20.0 * bound)[0] == 1.0


def test_levels_counted_over_their_distinct_boxes_are_the_same_counts():
    """The coordinator keeps a scene's level boxes once each (groups share coarse clusters' boxes, a
    level often keeps the one below's): the counts are those of every group's own boxes."""
    rng = np.random.default_rng(5)
    groups, levels = 60, 6
    lo = rng.uniform(-3.0, 3.0, size=(groups, levels, 3))
    boxes = np.concatenate([lo, lo + rng.uniform(0.01, 2.0, size=(groups, levels, 3))], axis=2)
    boxes[:, 3:] = boxes[:, 2:3]                            # levels that keep the one below's box
    boxes[groups // 2:, 4:] = boxes[:groups - groups // 2, 4:]   # boxes other groups share
    errors = np.cumsum(rng.uniform(0.0, 0.05, size=(groups, levels)), axis=1)
    errors[:, 0] = 0.0
    triangles = np.cumsum(rng.uniform(1.0, 100.0, size=(groups, levels))[:, ::-1], axis=1)[:, ::-1].copy()
    distinct, index = distinct_level_boxes(boxes)
    assert len(distinct) < groups * (levels - 1) and index.shape == (groups, levels - 1)
    projector = GroupProjector(boxes[:, 0], triangles[:, 0], BOUNDS, None, (640, 360)).with_levels(
        errors, triangles, boxes)
    chosen = set()
    for camera in random_cameras(BOUNDS / 2.0, 20, seed=6, nearest=0.5, widest_deg=100.0):
        for bound in (0.5, 2.0, 8.0):
            counts = level_counts(errors, triangles, boxes, camera, (640, 360), bound)
            assert np.array_equal(level_counts(errors, triangles, distinct, camera, (640, 360), bound, index), counts)
            expected = project_groups(boxes[:, 0], counts, camera, (640, 360), BOUNDS)
            assert np.array_equal(projector(camera, None, None, bound).weights, expected.weights)
            chosen.update(int(np.flatnonzero(triangles[g] == counts[g])[0]) for g in range(groups))
    assert len(chosen) >= 3, "the cameras choose levels of several depths"
