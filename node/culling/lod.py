"""Choosing levels of detail for a frame (issue 32), without GL: which clusters of a scene's
:class:`node.scene.lod.LodTree` (a cluster DAG) stand in for its full detail, for one camera and
frame size.

A group's error (world units) shows on screen as at most ``error`` times its box's error scale
(:func:`tessera.screen_error.error_scales`: ``s · (1 + tan²θ) / d``, ``d`` the distance from the eye
to the box's nearest point, infinite inside it: never coarse there, ``θ`` the largest angle off the
view axis its visible part reaches, ``s`` the frame's pixels per unit at depth 1). A cluster is
drawn when its own group's error fits ``error_px`` and its parent group's does not (:func:`lod_cut`);
a leaf's chunks are left to the coarse levels when its parent group fits.
Errors grow up the DAG while boxes only grow, so a group shows at least its inputs' errors from any
eye: the groups that fit are closed under their inputs, and the clusters drawn and the leaves left at
full detail cover the model exactly once.

The choice depends on the camera, the frame's size and the bound only — not on the tile — so
every tile of a frame, on every node, draws every part of the model at the same level, and tiles
join as the whole frame (they meet on the groups' locked borders, :mod:`node.scene.lod`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from node.culling.bvh import merge_touching
from node.scene.lod import LodTree
from tessera.geometry import Camera
from tessera.screen_error import error_scales


@dataclass(frozen=True, slots=True, eq=False)
class LodCut:
    """A frame's levels: ``nodes`` (K,) int64 the coarse clusters drawn (sorted), ``blocked_first`` /
    ``blocked_end`` (J,) int64 the chunk ranges they stand in for (not drawn at full detail), sorted;
    ``hidden`` the same ranges with touching ones merged (what the chunk tree's traversal skips:
    :func:`node.culling.bvh.cull`)."""

    nodes: np.ndarray
    blocked_first: np.ndarray
    blocked_end: np.ndarray
    hidden: tuple[np.ndarray, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "hidden", merge_touching(self.blocked_first, self.blocked_end))

    @classmethod
    def full(cls) -> LodCut:
        """Full detail: no coarse cluster."""
        empty = np.zeros(0, np.int64)
        return cls(empty, empty, empty)

    @property
    def coarse(self) -> bool:
        return bool(self.nodes.size)


def projected_errors(tree: LodTree, camera: Camera, size: tuple[int, int]) -> np.ndarray:
    """(G,) float64 each group's error on screen in pixels, seen from ``camera`` in a ``size`` frame
    (infinite where the eye is inside its box)."""
    scales = error_scales(camera, size, tree.group_boxes)
    with np.errstate(invalid="ignore"):
        return np.where(np.isinf(scales), np.inf, tree.group_error.astype(np.float64) * scales)


def lod_cut(tree: LodTree | None, camera: Camera, size: tuple[int, int], error_px: float) -> LodCut:
    """The coarsest clusters whose error on screen is at most ``error_px`` (0 or no tree: full detail)."""
    if tree is None or error_px <= 0.0 or tree.node_count == 0:
        return LodCut.full()
    fits = projected_errors(tree, camera, size) <= error_px
    fits = np.append(fits, False)   # index −1 (no group) never fits
    nodes = np.flatnonzero(fits[tree.own] & ~fits[tree.parent])
    blocked = fits[tree.leaf_group]
    return LodCut(nodes, tree.leaf_first_chunk[blocked], tree.leaf_end_chunk[blocked])


def subtract_ranges(first: np.ndarray, end: np.ndarray, cut_first: np.ndarray,
                    cut_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The parts of the sorted disjoint ranges [first, end) outside the sorted disjoint ranges
    [cut_first, cut_end), as sorted disjoint (first, end) arrays (int64)."""
    first, end = np.asarray(first, np.int64), np.asarray(end, np.int64)
    if first.size == 0 or cut_first.size == 0:
        return first, end
    # Coverage count along the line: +1 entering a kept range, −1 leaving; −1 entering a cut, +1 leaving.
    points = np.concatenate([first, end, cut_first, cut_end])
    steps = np.concatenate([np.ones_like(first), -np.ones_like(end), -np.ones_like(cut_first),
                            np.ones_like(cut_end)])
    order = np.lexsort((steps, points))
    points, level = points[order], np.cumsum(steps[order])
    inside = level == 1
    starts = np.flatnonzero(inside & np.concatenate(([True], ~inside[:-1])))
    stops = np.flatnonzero(~inside & np.concatenate(([False], inside[:-1])))
    lo, hi = points[starts], points[stops]
    keep = hi > lo
    return lo[keep], hi[keep]


def back_faces_hidden(closed: np.ndarray, boxes: np.ndarray, camera: Camera, size: tuple[int, int],
                      near: float) -> np.ndarray:
    """(B,) bool: the ``closed`` (B,) batches (:func:`node.scene.lod.closed_surface`: solids facing
    outwards) whose box (B, 2, 3) keeps clear of the near plane's rectangle at depth ``near`` of
    ``camera`` in a ``size`` frame (wholly beyond that plane, or farther from the eye than the
    rectangle's corners). Every ray of the frame
    then starts outside their solids and enters one through a front face before it meets a back
    face, so a frame that leaves their back faces out differs at most where a sample falls on a
    silhouette edge. Parts behind the eye do not matter: the near plane cuts them off the frame."""
    eye = np.asarray(camera.eye, np.float64)
    boxes = np.asarray(boxes, np.float64)
    distance = np.linalg.norm(np.clip(eye, boxes[:, 0], boxes[:, 1]) - eye, axis=1)
    half_y = math.tan(math.radians(camera.fovy_deg) / 2.0)
    corner = near * math.sqrt(1.0 + half_y * half_y * (1.0 + (size[0] / size[1]) ** 2))
    forward = np.asarray(camera.target, np.float64) - eye
    forward /= np.linalg.norm(forward)
    nearest = np.minimum(boxes[:, 0] * forward, boxes[:, 1] * forward).sum(axis=1) - eye @ forward
    return np.asarray(closed, bool) & ((distance > corner) | (nearest > near))


def boxes_in_frustum(boxes: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """(N,) bool: the boxes (N, 2, 3) not wholly outside any of ``planes`` (6, 4) (inside where
    a·x + b·y + c·z + d ≥ 0)."""
    center = (boxes[:, 0] + boxes[:, 1]).astype(np.float64) / 2.0
    extent = (boxes[:, 1] - boxes[:, 0]).astype(np.float64) / 2.0
    distance = center @ planes[:, :3].T + planes[:, 3]
    radius = extent @ np.abs(planes[:, :3]).T
    return np.all(distance + radius >= 0.0, axis=1)
