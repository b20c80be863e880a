"""Bounded tiles for a heavy session beside others (issue 19): no tile of one session holds a node
much longer than the other sessions' tiles take.

A node draws its queue in order, and a frame is out only when its last tile is, so while one
node draws a long tile every other session's frame with a tile queued behind it waits, however
idle the other nodes are. Measured: a session opening the 990k-triangle scan had its first frames
drawn whole by the one node holding it, 200-300 ms a tile on llvmpipe, while the four sessions
moving beside it drew 40-60 ms tiles; on the scheduler's virtual clock their longest gap went
from 0.26 to 0.46 s.

A tile's cost is expected from the session's last complete frame (:class:`CostField`: its tiles'
busy ms, each spread evenly over its rect: a piece of a scan's dense middle is expected dearer
than one of the empty sky). A session whose longest tile is expected (smoothed over its frames,
whatever pieces the frame before was cut into) to hold a node more than :data:`CUT_ABOVE` times
as long as the other busy sessions' frames hold one on average (their busy ms per node per frame,
smoothed: :func:`piece_bound_ms` of theirs is the bound), or that has no frame measured yet
beside busy others, has its frame's tiles cut into pieces of about the bound, handed out one at
a time, in fair turn, to the nodes holding its scene as they want work (the scheduler's part):
the other sessions' tiles queued on a node meanwhile are drawn between two pieces. A tile is cut
in two across its longer side where half its expected cost lies, the dearer piece again, until
every piece is expected within the bound (:func:`cut_heavy`), so the pieces are small where the
cost is dense and the field the next frame is cut by is finer there. A session with no frame
measured yet (a scene just loaded) is expected to cost, per primitive in view, what the other
sessions' frames cost per primitive of their scenes, spread as its primitive groups project
(:meth:`CostField.of_groups`, seed 003's DPBP boxes); a session of a scene without groups is not
cut before it is measured. Pure: rects in, rects out.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from tessera.balancers.base import Partition, ProjectedGroups, Tile
from tessera.geometry import Rect

#: A session's frames are cut only when they hold a node this many times as long as the others'
#: (a piece costs a tile's fixed overhead again: read-back, encoding, messages; and one noisy
#: frame of a session like the others must not cut its next).
CUT_ABOVE = 2.0
#: Fewest pixels of a piece's side.
MIN_PIECE_PX = 16
#: The least bound (ms): frames that hold a node for under twice this are never cut (on a GPU
#: every tile takes a few ms).
MIN_BOUND_MS = 10.0
#: Most pieces a frame is cut into.
MAX_PIECES = 64


@dataclass(frozen=True, eq=False)
class CostField:
    """Expected busy ms over a frame: ``boxes`` (K, 4) float64 pixel x0, y0, x1, y1 (origin
    top-left), ``ms`` (K,) float64 each box's cost, spread evenly over its area."""

    boxes: np.ndarray
    ms: np.ndarray

    @classmethod
    def of(cls, measured: Iterable[tuple[Rect, float]]) -> CostField:
        """The field of tiles measured: each (rect, busy ms)."""
        pairs = list(measured)
        boxes = np.array([[r.x, r.y, r.x1, r.y1] for r, _ in pairs], dtype=np.float64).reshape(-1, 4)
        return cls(boxes, np.array([ms for _, ms in pairs], dtype=np.float64))

    @classmethod
    def of_groups(cls, groups: ProjectedGroups, ms_per_primitive: float) -> CostField:
        """The projected primitive ``groups``, each costing ``ms_per_primitive`` per primitive."""
        return cls(np.asarray(groups.boxes, dtype=np.float64).reshape(-1, 4),
                   np.asarray(groups.weights, dtype=np.float64) * ms_per_primitive)

    def expected(self, rect: Rect) -> float:
        """``rect``'s expected busy ms: the share of each box's ms its area covers."""
        b = self.boxes
        w = np.clip(np.minimum(b[:, 2], rect.x1) - np.maximum(b[:, 0], rect.x), 0.0, None)
        h = np.clip(np.minimum(b[:, 3], rect.y1) - np.maximum(b[:, 1], rect.y), 0.0, None)
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        inside = np.divide(w * h, area, out=(w * h > 0).astype(np.float64), where=area > 0)
        return float(self.ms @ inside)

    def scaled(self, old: tuple[int, int], new: tuple[int, int]) -> CostField:
        """The field of an ``old`` (w, h) frame laid on a ``new`` one: boxes scaled, ms kept."""
        scale = np.array([new[0] / old[0], new[1] / old[1]] * 2)
        return CostField(self.boxes * scale, self.ms)


def piece_bound_ms(node_ms: Iterable[float]) -> float | None:
    """The bound of a session's tiles: the longest the other busy sessions' frames hold a node
    (``node_ms``: each one's busy ms per node per frame, smoothed), at least :data:`MIN_BOUND_MS`
    (None: no other session is busy, nothing waits on the session's tiles)."""
    longest = max(node_ms, default=None)
    return None if longest is None else max(longest, MIN_BOUND_MS)


def halves(rect: Rect, field: CostField) -> tuple[Rect, Rect] | None:
    """``rect`` cut in two across its longer side (that can be: both halves at least
    :data:`MIN_PIECE_PX`) where half its expected cost lies; None when it cannot be cut."""
    across_x = rect.w >= rect.h if min(rect.w, rect.h) >= 2 * MIN_PIECE_PX else rect.w >= 2 * MIN_PIECE_PX
    side = rect.w if across_x else rect.h
    if side < 2 * MIN_PIECE_PX:
        return None

    def parts(at: int) -> tuple[Rect, Rect]:
        if across_x:
            return Rect(rect.x, rect.y, at, rect.h), Rect(rect.x + at, rect.y, rect.w - at, rect.h)
        return Rect(rect.x, rect.y, rect.w, at), Rect(rect.x, rect.y + at, rect.w, rect.h - at)

    half = field.expected(rect) / 2.0
    lo, hi = MIN_PIECE_PX, side - MIN_PIECE_PX
    if half <= 0.0:
        return parts(side // 2)
    while lo < hi:   # the first cut whose first part holds half the cost
        mid = (lo + hi) // 2
        if field.expected(parts(mid)[0]) < half:
            lo = mid + 1
        else:
            hi = mid
    return parts(lo)


def cut_heavy(partition: Partition, field: CostField, hold_ms: float,
              bound_ms: float | None) -> tuple[Partition, tuple[float, ...] | None]:
    """``partition`` as is (and None) unless the session's tiles hold a node (``hold_ms``: its
    longest tile expected by ``field``, smoothed over its frames) over :data:`CUT_ABOVE` ×
    ``bound_ms`` (None: no bound, nothing waits); else its tiles cut, the
    dearest piece in two again and again, until every piece is expected within ``bound_ms`` (or
    cannot be cut, or there are :data:`MAX_PIECES`), all pulled, dearest first, with what each is
    charged when it goes: its expected ms, at least ``bound_ms`` (a piece's cost is known only
    when it is back; one expected too cheap would let the session take the next turns too).
    Still an exact cover of the frame."""
    if bound_ms is None or not bound_ms > 0.0 or hold_ms <= CUT_ABOVE * bound_ms:
        return partition, None
    pieces = [(field.expected(t.rect), t.rect) for t in partition.tiles]
    done: list[tuple[float, Rect]] = []
    while pieces and len(pieces) + len(done) < MAX_PIECES:
        pieces.sort(key=lambda piece: piece[0])
        cost, rect = pieces.pop()
        cut = halves(rect, field) if cost > bound_ms else None
        if cut is None:
            done.append((cost, rect))
            continue
        pieces += [(field.expected(part), part) for part in cut]
    done += pieces
    if len(done) == len(partition.tiles):
        return partition, None
    done.sort(key=lambda piece: -piece[0])
    return Partition(tuple(Tile(rect, None) for _, rect in done), pull=True), tuple(max(ms, bound_ms) for ms, _ in done)


def longest_tile(partition: Partition, field: CostField) -> float:
    """The expected busy ms of ``partition``'s dearest tile."""
    return max(field.expected(tile.rect) for tile in partition.tiles)

