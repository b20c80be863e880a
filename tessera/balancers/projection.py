"""Screen-space footprints of world-space boxes (seed 003 §3, DPBP: primitive groups' 3D boxes
projected to 2D each frame and clipped to the screen), and the groups of a scene state (issue 11:
each group moved with its object before it is projected). Pure numpy."""

from __future__ import annotations

import numpy as np

from tessera.balancers.base import ProjectedGroups
from tessera.geometry import Camera, view_projection
from tessera.scene.graph import ObjectGraph, transform_boxes
from tessera.scene.state import SceneState
from tessera.screen_error import error_scales

_CORNERS = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)


#: Boxes projected at a time: the corners' temporaries of a block stay near 10 MB, whatever the count
#: (a sort-last node projects every chunk of its share in view: 147k chunks of the 24.8M-triangle
#: model took 112 MB at once, a fifth of the node's peak).
BOX_BLOCK = 1 << 14


def project_boxes(boxes: np.ndarray, camera: Camera, size: tuple[int, int], scene_bounds: np.ndarray) -> np.ndarray:
    """Pixel rectangles (K, 4) float64 x0, y0, x1, y1 (origin top-left, clipped to the screen) of
    world AABBs ``boxes`` (K, 6) x0, y0, z0, x1, y1, z1. A box reaching behind the eye covers
    the whole screen (conservative); a box entirely behind it or off screen is empty (x0 == x1).
    Projected :data:`BOX_BLOCK` boxes at a time."""
    boxes = np.asarray(boxes).reshape(-1, 6)
    matrix = view_projection(camera, size, scene_bounds)
    out = np.empty((boxes.shape[0], 4), np.float64)
    for first in range(0, boxes.shape[0], BOX_BLOCK):
        _project_block(boxes[first:first + BOX_BLOCK], matrix, size, out[first:first + BOX_BLOCK])
    return out


def _project_block(boxes: np.ndarray, matrix: np.ndarray, size: tuple[int, int], out: np.ndarray) -> None:
    """:func:`project_boxes` of ``boxes`` (k, 6) by view-projection ``matrix`` (4, 4) into ``out`` (k, 4)."""
    width, height = size
    boxes = boxes.astype(np.float64, copy=False)
    lo, hi = boxes[:, None, :3], boxes[:, None, 3:]
    corners = lo + (hi - lo) * _CORNERS[None]
    clip = np.einsum("ij,kcj->kci", matrix, np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=2))
    w = clip[..., 3]
    in_front = w > 1e-9
    safe_w = np.where(in_front, w, 1.0)
    px = (clip[..., 0] / safe_w * 0.5 + 0.5) * width
    py = (0.5 - clip[..., 1] / safe_w * 0.5) * height
    big = np.float64(np.finfo(np.float32).max)
    out[:] = np.stack([np.where(in_front, px, big).min(1), np.where(in_front, py, big).min(1),
                       np.where(in_front, px, -big).max(1), np.where(in_front, py, -big).max(1)], axis=1)
    straddles = in_front.any(1) & ~in_front.all(1)
    out[straddles] = [0.0, 0.0, width, height]
    out[:, [0, 2]] = np.clip(out[:, [0, 2]], 0.0, width)
    out[:, [1, 3]] = np.clip(out[:, [1, 3]], 0.0, height)
    empty = ~in_front.any(1) | (out[:, 2] <= out[:, 0]) | (out[:, 3] <= out[:, 1])
    out[empty] = 0.0


def project_groups(boxes: np.ndarray, counts: np.ndarray, camera: Camera, size: tuple[int, int],
                   scene_bounds: np.ndarray) -> ProjectedGroups:
    """Projected, clipped boxes and their primitive counts, empty footprints dropped."""
    rects = project_boxes(boxes, camera, size, scene_bounds)
    keep = rects[:, 2] > rects[:, 0]
    return ProjectedGroups(rects[keep], np.asarray(counts, dtype=np.float64).reshape(-1)[keep])


def posed_groups(boxes: np.ndarray, counts: np.ndarray, owners: np.ndarray, graph: ObjectGraph,
                 state: SceneState) -> tuple[np.ndarray, np.ndarray]:
    """The base-pose world groups ``boxes`` (K, 6) with ``counts`` (K,) of objects ``owners`` (K,)
    int64 (indices into ``graph``) in ``state``: hidden objects' groups dropped, moved objects'
    boxes moved by their model matrices (:func:`tessera.scene.graph.transform_boxes`, a box around
    the moved box). Returns (K', 6) float64 boxes and (K',) float64 counts."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
    owners = np.asarray(owners, dtype=np.int64).reshape(-1)
    keep = graph.visibility(state)[owners]
    boxes, owners = boxes[keep], owners[keep]
    models = graph.model_matrices(state)
    moved = ~(models[owners] == np.identity(4)).all(axis=(1, 2))
    if moved.any():
        boxes = boxes.copy()
        boxes[moved] = transform_boxes(boxes[moved].reshape(-1, 2, 3), models[owners[moved]]).reshape(-1, 6)
    return boxes, np.asarray(counts, dtype=np.float64).reshape(-1)[keep]


def level_counts(errors: np.ndarray, triangles: np.ndarray, boxes: np.ndarray, camera: Camera,
                 size: tuple[int, int], error_px: float, index: np.ndarray | None = None) -> np.ndarray:
    """(K,) float64 triangles each group draws at the levels of detail within ``error_px``: of
    groups whose levels (0: full detail … L) have ``errors`` and ``triangles`` (K, L + 1) over
    ``boxes`` (K, L + 1, 6), the coarsest level whose error, seen from ``camera`` in a ``size`` frame
    (:func:`tessera.screen_error.error_scales` of its box), is at most ``error_px`` pixels (as
    nodes choose: :func:`node.culling.lod.lod_cut`, here per group). With ``index`` (K, L) int64,
    ``boxes`` are (U, 6) distinct boxes and level k ≥ 1 of group g is ``boxes[index[g, k - 1]]``
    (:func:`distinct_level_boxes`): each box's scale worked out once."""
    errors = np.asarray(errors, np.float64)
    if errors.shape[1] < 2:
        return np.asarray(triangles, np.float64)[:, 0]
    if index is None:
        scales = error_scales(camera, size, np.asarray(boxes, np.float64).reshape(*np.shape(errors), 2, 3))[:, 1:]
    else:
        scales = error_scales(camera, size, np.asarray(boxes, np.float64).reshape(-1, 2, 3))[index]
    with np.errstate(invalid="ignore"):
        fits = errors[:, 1:] * scales <= error_px   # level 0 (full detail) always fits
    coarsest = np.where(fits.any(axis=1), errors.shape[1] - 1 - np.argmax(fits[:, ::-1], axis=1), 0)
    return triangles[np.arange(len(errors)), coarsest]


def distinct_level_boxes(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct boxes (U, 6) float64 of levels 1 … L of ``boxes`` (K, L + 1, 6) and where each
    group's level k ≥ 1 finds its own, (K, L) int64: :func:`level_counts`' ``boxes`` and
    ``index`` (the 24.8M-triangle model's 512 groups × 11 levels have 1 394 boxes: a quarter)."""
    boxes = np.asarray(boxes, np.float64)
    distinct, index = np.unique(boxes[:, 1:].reshape(-1, 6), axis=0, return_inverse=True)
    return distinct, index.reshape(boxes.shape[0], boxes.shape[1] - 1)


class GroupProjector:
    """A scene's world-space primitive groups ``boxes`` (K, 6) at the base pose with primitive
    ``counts`` (K,), its ``bounds`` (2, 3) and each group's object ``owners`` (K,) (indices into
    the scene's objects; None: the groups never move), projected for a ``size`` frame: called with
    a camera, a frame's state and the scene's object graph, each group moved with its object,
    hidden objects' groups dropped, near/far from the state's bounds (:func:`posed_groups`); the
    base pose without a state or a graph. With ``levels`` ((K, L + 1) errors and triangles and
    (K, L + 1, 6) boxes, issue 32; kept as :func:`level_counts` takes them with an ``index``) and a
    frame's levels-of-detail bound, a group counts the triangles its level draws (:func:`level_counts`;
    groups of moved objects, drawn at full detail, count them all)."""

    def __init__(self, boxes: np.ndarray, counts: np.ndarray, bounds: np.ndarray, owners: np.ndarray | None,
                 size: tuple[int, int],
                 levels: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        self.boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
        self.counts = np.asarray(counts, dtype=np.float64).reshape(-1)
        self.bounds = np.asarray(bounds, dtype=np.float64)
        self.owners = None if owners is None else np.asarray(owners, dtype=np.int64).reshape(-1)
        self.size = size
        self.levels = levels

    def for_size(self, size: tuple[int, int]) -> GroupProjector:
        """The same groups projected for a ``size`` frame."""
        return GroupProjector(self.boxes, self.counts, self.bounds, self.owners, size, self.levels)

    def with_levels(self, errors: np.ndarray, triangles: np.ndarray, boxes: np.ndarray) -> GroupProjector:
        """The same groups with their levels of detail (:func:`level_counts`'s arrays)."""
        distinct, index = distinct_level_boxes(np.asarray(boxes, np.float64).reshape(len(errors), -1, 6))
        return GroupProjector(self.boxes, self.counts, self.bounds, self.owners, self.size,
                              (np.asarray(errors, np.float64), np.asarray(triangles, np.float64), distinct, index))

    def __call__(self, camera: Camera, state: SceneState | None, graph: ObjectGraph | None,
                 lod_error_px: float | None = None) -> ProjectedGroups:
        counts = self.counts
        moves = state is not None and self.owners is not None and graph is not None
        if self.levels is not None and lod_error_px:
            errors, triangles, distinct, index = self.levels
            counts = level_counts(errors, triangles, distinct, camera, self.size, lod_error_px, index)
            if moves:
                assert state is not None and graph is not None and self.owners is not None
                moved = graph.moved(state)[self.owners]
                counts = np.where(moved, self.counts, counts)
        if not moves:
            return project_groups(self.boxes, counts, camera, self.size, self.bounds)
        assert state is not None and graph is not None and self.owners is not None
        seen = graph.bounds(state)
        posed, weights = posed_groups(self.boxes, counts, self.owners, graph, state)
        return project_groups(posed, weights, camera, self.size, self.bounds if seen is None else seen)
