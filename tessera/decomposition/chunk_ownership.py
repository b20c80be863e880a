"""Chunk ownership for the hybrid sort-first/sort-last partition (seed 000 §4.4).

The screen is still cut into disjoint tiles by the balancers. Each chunk (an octree piece of the
scene, :mod:`node.scene.chunks`) is owned by exactly one tile per frame, by where its projected
bound falls, and only its owner draws it, also beyond the tile's edge: every tile draws into and
reads back colour and depth of its tile grown by a fixed-width border strip (the seed's choice over
the minimal rectangle or a full-height band, which cost O(objects)), and the strips are merged by
depth (:mod:`tessera.compositing.depth_merge`). A chunk whose bound does not fit inside any tile's strip
is *shared*: drawn by every tile it touches, as in plain sort-first. Only the strips need depth
(the seed's Fig. 4.6): a tile's core, :func:`exclusive_rect`, is reached by no other tile and
travels as colour alone.

Where the seed is vague, this module decides:

- The owner is the tile holding the centre of the chunk's projected bound, provided the bound fits
  in that tile's read-back rect; otherwise the lowest-numbered tile whose read-back rect holds it
  (tiles of uneven sizes); otherwise the chunk is shared.
- Bounds are grown by ``margin_px`` (1 px) before the tests, as the culler pads its tile frustum:
  the bound is a float64 projection of the chunk's box, GL rasterizes float32 vertices, and a pixel
  is drawn when its centre is covered, so every pixel a chunk can write then lies inside the bound.
- Bounds and rects are clipped to the frame, so a chunk against the frame's edge still fits a tile
  there with a strip of 0.
- The result depends only on the bounds, the tiles and the strip: every node computes the same
  owner for the chunks it looks at, so ownership needs no messages (the seed's implicit,
  per-server model partition).
- Blended chunks (glTF ``BLEND``) write no depth, and their colour depends on everything drawn
  behind them, which a tile's layer holds only in part: a tile that a blended chunk's bound
  touches is drawn *complete* (every chunk touching it, as in sort-first, besides those it owns)
  and all of it is final as drawn: its core is the whole tile. Its neighbours' strips reach into
  it but are pasted over; any blended fragment in a strip lies in such a tile (the chunk's bound
  touches it), so merging by depth stays exact for the other tiles.

Why the merge is exact: a pixel p lies in exactly one tile V. A chunk that covers p is either owned,
and then its owner's read-back rect holds all of its pixels, p included, or shared, and then it
touches V, so V draws it. Every fragment nearest at p is therefore in some layer at p, and every
layer holds true fragments of the scene under the one projection: the nearest over the layers is
the nearest of the whole frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tessera.geometry import Rect

#: Owner of a chunk drawn by every tile it touches.
SHARED = -1
#: Owner of a chunk with no pixel in the frame (an empty projected bound).
OFF_SCREEN = -2
#: Bounds are grown by this many pixels before testing them against tiles and strips.
DEFAULT_MARGIN_PX = 1.0
#: The border strip's default width (``--depth-strip``): the narrowest that kept the hybrid's
#: redundancy within 1.02 on the Pan's orbit, zoom and fly-through (bench.compose's strip sweep,
#: docs/benchmarks/compose.md).
DEFAULT_DEPTH_STRIP = 32


@dataclass(frozen=True, eq=False)
class Ownership:
    """One frame's hybrid assignment of K chunks to T tiles.

    ``owner`` (K,) int64: the owning tile's index, :data:`SHARED` or :data:`OFF_SCREEN`;
    ``draws``: per tile, (n_t,) int64 sorted indices (into the K chunks) of what it draws — the
    chunks it owns and the shared ones touching it (a complete tile: every chunk touching it,
    too); ``readback``: per tile, the rect it draws into and reads back (the tile grown by the
    strip, clipped to the frame); ``complete`` (T,) bool: tiles a blended chunk touches.
    """

    owner: np.ndarray
    draws: tuple[np.ndarray, ...]
    readback: tuple[Rect, ...]
    complete: np.ndarray


def core_rect(tile: Rect, strip_px: int, size: tuple[int, int], complete: bool = False) -> Rect | None:
    """What of ``tile`` is final as its node drew it and travels as colour alone: the whole tile
    when it is drawn complete, else :func:`exclusive_rect`."""
    return tile if complete else exclusive_rect(tile, strip_px, size)


def readback_rect(tile: Rect, strip_px: int, size: tuple[int, int]) -> Rect:
    """``tile`` grown by ``strip_px`` on every side, clipped to the ``size`` = (w, h) frame."""
    width, height = size
    x0, y0 = max(tile.x - strip_px, 0), max(tile.y - strip_px, 0)
    x1, y1 = min(tile.x1 + strip_px, width), min(tile.y1 + strip_px, height)
    return Rect(x0, y0, x1 - x0, y1 - y0)


def exclusive_rect(tile: Rect, strip_px: int, size: tuple[int, int]) -> Rect | None:
    """The part of ``tile`` that no other tile's read-back rect reaches, for tiles that cover the
    ``size`` = (w, h) frame exactly: the tile shrunk by ``strip_px`` on every side not on the frame's
    edge (every such side has a neighbour, whose strip reaches ``strip_px`` in). Only the strips
    need depth (seed 000 Fig. 4.6, the area "that requires sending Z-buffer"): these pixels are
    final as the tile drew them and travel as colour alone. None when nothing is left."""
    width, height = size
    x0 = tile.x + (strip_px if tile.x > 0 else 0)
    y0 = tile.y + (strip_px if tile.y > 0 else 0)
    x1 = tile.x1 - (strip_px if tile.x1 < width else 0)
    y1 = tile.y1 - (strip_px if tile.y1 < height else 0)
    return Rect(x0, y0, x1 - x0, y1 - y0) if x1 > x0 and y1 > y0 else None


def assign_chunks(bounds: np.ndarray, tiles: Sequence[Rect], strip_px: int, size: tuple[int, int],
                  margin_px: float = DEFAULT_MARGIN_PX, blended: np.ndarray | None = None) -> Ownership:
    """Owners and per-tile draw lists of chunks with projected ``bounds`` (K, 4) float64 pixels x0,
    y0, x1, y1 (origin top-left, clipped to the frame, empty where x1 ≤ x0 or y1 ≤ y0, as
    :func:`tessera.balancers.projection.project_boxes` gives them), for ``tiles`` that cover the ``size``
    frame exactly, with border strips ``strip_px`` ≥ 0 wide; ``blended`` (K,) bool marks the
    chunks that blend (None: none). Cost O(K × T) in numpy."""
    if strip_px < 0:
        raise ValueError(f"the depth strip must be >= 0 px, got {strip_px}")
    if not tiles:
        raise ValueError("need at least one tile")
    bounds = np.asarray(bounds, dtype=np.float64).reshape(-1, 4)
    width, height = size
    readback = tuple(readback_rect(tile, strip_px, size) for tile in tiles)
    on_screen = (bounds[:, 2] > bounds[:, 0]) & (bounds[:, 3] > bounds[:, 1])
    grown = np.clip(bounds + np.array([-margin_px, -margin_px, margin_px, margin_px]),
                    0.0, [width, height, width, height])
    tile_box = np.array([(t.x, t.y, t.x1, t.y1) for t in tiles], dtype=np.float64)
    read_box = np.array([(r.x, r.y, r.x1, r.y1) for r in readback], dtype=np.float64)
    fits = ((grown[:, None, 0] >= read_box[:, 0]) & (grown[:, None, 1] >= read_box[:, 1])
            & (grown[:, None, 2] <= read_box[:, 2]) & (grown[:, None, 3] <= read_box[:, 3]))
    touches = ((grown[:, None, 0] < tile_box[:, 2]) & (grown[:, None, 2] > tile_box[:, 0])
               & (grown[:, None, 1] < tile_box[:, 3]) & (grown[:, None, 3] > tile_box[:, 1]))
    centre_x, centre_y = (bounds[:, 0] + bounds[:, 2]) / 2.0, (bounds[:, 1] + bounds[:, 3]) / 2.0
    holds_centre = ((centre_x[:, None] >= tile_box[:, 0]) & (centre_x[:, None] < tile_box[:, 2])
                    & (centre_y[:, None] >= tile_box[:, 1]) & (centre_y[:, None] < tile_box[:, 3]))
    preferred = fits & holds_centre
    owner = np.where(preferred.any(axis=1), preferred.argmax(axis=1),
                     np.where(fits.any(axis=1), fits.argmax(axis=1), SHARED)).astype(np.int64)
    owner[~on_screen] = OFF_SCREEN
    shared = owner == SHARED
    touches &= on_screen[:, None]
    complete = np.zeros(len(tiles), dtype=bool) if blended is None else \
        (touches & np.asarray(blended, dtype=bool)[:, None]).any(axis=0)
    draws = tuple(np.flatnonzero((owner == t) | ((shared | complete[t]) & touches[:, t])) for t in range(len(tiles)))
    return Ownership(owner, draws, readback, complete)
