"""Sort-last data partition: the database decomposition that seed 000 §4.4 sets its hybrid against
(sort-last: "each primitive drawn only once", at the price of merging whole images by depth), with
node shares sized by the calibrated speeds of seed 003 §1.

The scene's chunks are split into N spatially coherent shares, one per node, by recursive
bisection: the nodes are halved (the performance tree of seed 003 §2: left ⌈n/2⌉ nodes, split
ratio = their summed weight over the whole), the chunks are ordered along the longest axis of their
centres' box and cut where the running triangle count reaches that ratio, and both halves recurse.
Each share is then a box-like region of the model, so its projection, the rect a node reads back
(IceT's bounding-box read-back, :func:`covering_rect`), stays small.

Triangles are the weight: a sort-last node renders the whole frame, so its share's cost is
geometry, not pixels. The result depends only on the chunks and the weights (stable sorts, no
randomness): every node computes the same partition from the same scene file.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tessera.geometry import Rect


def split_chunks(boxes: np.ndarray, triangles: np.ndarray, weights: Sequence[float]) -> np.ndarray:
    """(C,) int64 share (0 … N−1) of each chunk, for chunk ``boxes`` (C, 2, 3) world [min, max],
    ``triangles`` (C,) counts and N node ``weights`` (> 0, e.g. calibrated speeds Pᵢ): share i
    holds about weights[i] / Σ weights of the triangles, off by at most one chunk per bisection
    level. Shares may be empty when there are fewer chunks than nodes."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    triangles = np.asarray(triangles, dtype=np.int64).reshape(-1)
    node_weights = np.asarray(weights, dtype=np.float64).reshape(-1)
    if triangles.shape[0] != boxes.shape[0]:
        raise ValueError(f"{boxes.shape[0]} boxes but {triangles.shape[0]} triangle counts")
    if node_weights.size == 0 or not np.all(np.isfinite(node_weights) & (node_weights > 0.0)):
        raise ValueError(f"node weights must be finite and > 0, got {list(weights)}")
    centres = boxes.mean(axis=1)
    share = np.zeros(boxes.shape[0], np.int64)
    pending = [(np.arange(boxes.shape[0]), 0, node_weights.size)]
    while pending:
        chunks, first, end = pending.pop()
        if end - first == 1:
            share[chunks] = first
            continue
        middle = first + math.ceil((end - first) / 2)
        ratio = node_weights[first:middle].sum() / node_weights[first:end].sum()
        cut_chunks = _cut(centres[chunks], triangles[chunks], ratio)
        pending.append((chunks[cut_chunks[0]], first, middle))
        pending.append((chunks[cut_chunks[1]], middle, end))
    return share


def _cut(centres: np.ndarray, triangles: np.ndarray, ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions (into ``centres`` (K, 3)) of the two sides of a cut across the longest axis of the
    centres' box, the first side holding the share ``ratio`` of ``triangles`` (K,) as nearly as a
    cut between two chunks allows."""
    if centres.shape[0] == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty
    axis = int(np.argmax(centres.max(axis=0) - centres.min(axis=0)))
    order = np.argsort(centres[:, axis], kind="stable")
    running = np.concatenate(([0], np.cumsum(triangles[order])))
    cut = int(np.argmin(np.abs(running - ratio * running[-1])))
    return order[:cut], order[cut:]


def covering_rect(bounds: np.ndarray, size: tuple[int, int], margin_px: float = 1.0) -> Rect | None:
    """The integer rect of the ``size`` = (w, h) frame that holds every pixel of projected
    ``bounds`` (K, 4) float64 x0, y0, x1, y1 (empty ones, x1 ≤ x0 or y1 ≤ y0, ignored), grown by
    ``margin_px`` for float32 rasterization; None when none is on screen. What a sort-last node
    reads back: the rect its share projects to."""
    bounds = np.asarray(bounds, dtype=np.float64).reshape(-1, 4)
    bounds = bounds[(bounds[:, 2] > bounds[:, 0]) & (bounds[:, 3] > bounds[:, 1])]
    if bounds.shape[0] == 0:
        return None
    width, height = size
    x0 = max(math.floor(bounds[:, 0].min() - margin_px), 0)
    y0 = max(math.floor(bounds[:, 1].min() - margin_px), 0)
    x1 = min(math.ceil(bounds[:, 2].max() + margin_px), width)
    y1 = min(math.ceil(bounds[:, 3].max() + margin_px), height)
    if x1 <= x0 or y1 <= y0:
        return None
    return Rect(x0, y0, x1 - x0, y1 - y0)
