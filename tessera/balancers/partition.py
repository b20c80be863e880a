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

    The screen is cut along every rect edge (coordinate compression: at most (2T+1)² cells for T
    rects, usually far fewer) and each rect's cover counted there, so the cost does not grow with
    the pixel count.
    """
    width, height = size
    for rect in rects:
        if not all(isinstance(v, int) for v in (rect.x, rect.y, rect.w, rect.h)):
            raise ValueError(f"non-integer rect {rect}")
        if rect.w <= 0 or rect.h <= 0 or rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
            raise ValueError(f"rect {rect} is empty or outside the {width}x{height} screen")
    boxes = np.array([(r.x, r.y, r.x1, r.y1) for r in rects], dtype=np.int64).reshape(-1, 4)
    xs = np.unique(np.concatenate([[0, width], boxes[:, 0], boxes[:, 2]]))
    ys = np.unique(np.concatenate([[0, height], boxes[:, 1], boxes[:, 3]]))
    cover = np.zeros((len(ys), len(xs)), dtype=np.int64)
    x0, x1 = np.searchsorted(xs, boxes[:, 0]), np.searchsorted(xs, boxes[:, 2])
    y0, y1 = np.searchsorted(ys, boxes[:, 1]), np.searchsorted(ys, boxes[:, 3])
    np.add.at(cover, (y0, x0), 1)
    np.add.at(cover, (y0, x1), -1)
    np.add.at(cover, (y1, x0), -1)
    np.add.at(cover, (y1, x1), 1)
    cells = cover.cumsum(0).cumsum(1)[:-1, :-1]
    if cells.size == 0 or cells.min() != 1 or cells.max() != 1:
        low, high = (int(cells.min()), int(cells.max())) if cells.size else (0, 0)
        raise ValueError(f"rects do not cover the {width}x{height} screen exactly once (min {low}, max {high})")
