"""Screen partition math (pure): the strips→tiles topology of seed 000 §4.2 (Fig. 4.2), integer
splitting of a length by weights, and the exact-cover check every balancer must pass.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tessera.geometry import Rect


def strip_counts(n: int, size: tuple[int, int]) -> list[int]:
    """Tiles per horizontal strip for ``n`` tiles on a ``size`` = (w, h) screen.

    Seed 000 Fig. 4.2: the screen is cut into strips, then each strip into tiles; the number of
    strips is chosen so that equal-area tiles are as square as possible; when ``n`` is not a
    multiple of the strip count the first strips hold one tile more.
    """
    if n < 1:
        raise ValueError(f"need at least one tile, got {n}")
    width, height = size
    rows = min(n, max(1, round(math.sqrt(n * height / width))))
    base, extra = divmod(n, rows)
    return [base + 1 if i < extra else base for i in range(rows)]


def split_length(total: int, weights: Sequence[float], minimum: int = 1) -> list[int]:
    """Integer lengths summing to ``total``, proportional to ``weights``, each ≥ ``minimum``.

    Cumulative rounding keeps the error of every edge under one pixel.
    """
    count = len(weights)
    if count * minimum > total:
        raise ValueError(f"cannot split {total} px into {count} parts of at least {minimum} px")
    w = np.maximum(np.asarray(weights, dtype=np.float64), 0.0)
    if not np.isfinite(w).all() or w.sum() <= 0.0:
        w = np.ones(count)
    edges = np.rint(np.cumsum(w) / w.sum() * total).astype(np.int64)
    edges[-1] = total
    return clamp_edges([0, *edges.tolist()], total, minimum)


def clamp_edges(edges: Sequence[int], total: int, minimum: int = 1) -> list[int]:
    """Lengths between ``edges`` (0 = first, ``total`` = last) after pushing inner edges apart so
    that every part is at least ``minimum`` pixels."""
    pos = [int(e) for e in edges]
    count = len(pos) - 1
    pos[0], pos[-1] = 0, total
    for i in range(1, count):
        pos[i] = min(max(pos[i], pos[i - 1] + minimum), total - (count - i) * minimum)
    return [pos[i + 1] - pos[i] for i in range(count)]


def strips_to_rects(size: tuple[int, int], heights: Sequence[int], widths: Sequence[Sequence[int]]) -> list[Rect]:
    """Row-major rects from strip heights and, per strip, tile widths."""
    rects = []
    y = 0
    for height, row in zip(heights, widths, strict=True):
        x = 0
        for width in row:
            rects.append(Rect(x, y, width, height))
            x += width
        y += height
    return rects


def equal_strip_partition(n: int, size: tuple[int, int], minimum: int = 1) -> list[Rect]:
    """Equal-area tiles in the strips→tiles topology: strip heights ∝ their tile counts."""
    counts = strip_counts(n, size)
    heights = split_length(size[1], counts, minimum)
    widths = [split_length(size[0], [1.0] * c, minimum) for c in counts]
    return strips_to_rects(size, heights, widths)


def check_exact_cover(rects: Sequence[Rect], size: tuple[int, int]) -> None:
    """Raise ValueError unless ``rects`` are integer, inside the screen, non-empty, disjoint and
    cover all of it.

    Disjoint rects inside the screen whose areas sum to the screen's cover it exactly, so the
    check is O(T²) over the T rects (pairwise overlaps, vectorised), independent of the pixel count.
    """
    width, height = size
    for rect in rects:
        if not all(isinstance(v, int) for v in (rect.x, rect.y, rect.w, rect.h)):
            raise ValueError(f"non-integer rect {rect}")
        if rect.w <= 0 or rect.h <= 0 or rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
            raise ValueError(f"rect {rect} is empty or outside the {width}x{height} screen")
    boxes = np.array([(r.x, r.y, r.x1, r.y1) for r in rects], dtype=np.int64).reshape(-1, 4)
    overlap_w = np.minimum(boxes[:, None, 2], boxes[None, :, 2]) - np.maximum(boxes[:, None, 0], boxes[None, :, 0])
    overlap_h = np.minimum(boxes[:, None, 3], boxes[None, :, 3]) - np.maximum(boxes[:, None, 1], boxes[None, :, 1])
    overlapping = (overlap_w > 0) & (overlap_h > 0)
    np.fill_diagonal(overlapping, False)
    area = int(((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).sum())
    if overlapping.any() or area != width * height:
        raise ValueError(f"rects do not cover the {width}x{height} screen exactly once "
                         f"({int(overlapping.sum()) // 2} overlapping pairs, {area} of {width * height} px)")
