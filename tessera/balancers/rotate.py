"""``rotate`` — seed 000 §4.3: tile distribution (rotation) over the damped adaptive partition.

Tiles are not bound to nodes: the coordinator hands them out in list order to whichever node is
free first (at a frame start, the fastest first), each node pulling the next tile until the frame
is done (the pull dispatch of :class:`tessera.scheduling.scheduler.FrameScheduler`). The list is the
``adaptive`` partition (§4.2: strips→tiles, damped edges, same effort estimate) of
``tiles_per_node`` × N tiles of estimated effort by round (below), ordered heaviest first by last
frame's time — a tile's predicted effort is last frame's measured load inside its rect, i.e. last frame's
tile time when its edges did not move.

How many tiles: the seed hands out N and relies on a node that finishes early moving on to the
next *frame*; with frames in flight capped that helps only across frame boundaries. With more
tiles than nodes the pull also evens out a frame by itself (longest-first list scheduling): with
k equal tiles per node each node usually pulls k, and when the estimate is off the light tiles
fill the gaps. k = 3 by default: on the synthetic maps of tests/test_balancers.py nodes are ≥ 95 %
busy from the 4th frame and ≥ 96 % once edges settle, 98.5 % on a moving hot spot, where k = 1
(the seed's N tiles) is only as good as ``adaptive``. Each tile costs a dispatch and a read-back,
so k is a parameter. Homogeneous clusters, as the seed says: speed weights only convert measured
times to effort. Timings are busy time.

Tile shares shrink round by round while frames overlap (factoring, Hummel, Schonberg & Flynn
1992). Longest-first list scheduling is only as even as its last tiles are small. With frames in
flight the nodes come to a frame staggered by the last frame's tail, and with equal tiles the
first one there pulled a tile more than the last (Lucy's orbit, 4 nodes: a frame's busiest node
up to 1.4× the mean, per-frame efficiency 0.92). So the N tiles of round r (the r-th each node
pulls) get effort ∝ ratioʳ, the ratio being the measured error e of a partition's tiles against
their planned efforts (the relative error of a tile weighted by its effort, :func:`estimate_error`,
measured when its timings come back: the estimate's error, and how far the damped edges were from
their targets), within [:data:`MIN_RATIO`, 1] (:func:`round_ratio`): each round's tiles are about
as large as one tile's error of the round before, which is what the next round must make up;
smaller rounds leave a frame's last tiles, and so the stagger with which the nodes come to the
next, smaller. Equal tiles (ratio 1) while frames come one at a time (the timings are of the last
partition made: every node starts the next frame together, and equal tiles settle fastest), and
until an estimate has been checked.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.base import BalanceInput, Partition, Tile
from tessera.balancers.support.load import measured_ms, speed_of
from tessera.geometry import Rect

#: Partitions whose tiles' planned efforts are kept until their timings come back (frames in flight).
KEPT_PLANS = 8
#: The smallest ratio between successive rounds' shares: below it a third round's tiles would hold
#: 2 % of a node's share, little but their per-tile overhead (read-back, encode).
MIN_RATIO = 0.15


def estimate_error(predicted: Sequence[float], measured: Sequence[float]) -> float:
    """How far tiles' measured times (ms) were from their predicted efforts (ms): the L1 distance
    of the two as shares of their totals, 0 (exact) … 2 — Σ sharesᵢ × |relative errorᵢ|, the
    relative error of a tile weighted by its effort, when the totals agree; 2 when either total
    is not positive."""
    p_total, m_total = sum(predicted), sum(measured)
    if not (p_total > 0.0 and m_total > 0.0):
        return 2.0
    return sum(abs(p / p_total - m / m_total) for p, m in zip(predicted, measured, strict=True))


def round_ratio(error: float, rounds: int) -> float:
    """The ratio r between successive rounds' tile shares: the estimate's ``error`` (the relative
    error of a tile weighted by its effort, :func:`estimate_error`) within [:data:`MIN_RATIO`, 1],
    so that a round's tile is about as large as the error of one tile of the round before; 1 with
    one round."""
    if rounds < 2:
        return 1.0
    return float(min(max(error, MIN_RATIO), 1.0))


def round_shares(count: int, nodes: int, ratio: float) -> list[float]:
    """Effort share of each of ``count`` tiles pulled by ``nodes`` nodes (relative, row-major):
    tile i is in round i // ``nodes`` and gets ``ratio`` to that power."""
    return [ratio ** (i // nodes) for i in range(count)]


class RotateBalancer(AdaptiveBalancer):
    name = "rotate"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"tau_ms": 200.0, "min_tile_px": 16, "tiles_per_node": 3}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        #: the last partitions' rects → (serial number, their tiles' planned efforts in ms)
        self.planned: dict[tuple[Rect, ...], tuple[int, list[float]]] = {}
        #: partitions made, the ratio between rounds' shares of the last, and whether its rects
        #: repeated the one's before (then its timings cannot tell the two apart)
        self.serial, self.ratio, self.repeated = 0, 1.0, False

    def validate_params(self) -> None:
        super().validate_params()
        if self.params["tiles_per_node"] < 1:
            raise ValueError("tiles_per_node must be >= 1")

    def partition(self, inputs: BalanceInput) -> Partition:
        """k × N tiles (fewer on screens too small for them, never fewer than N) of
        :func:`round_shares`, heaviest first."""
        width, height = inputs.size
        nodes = len(inputs.node_ids)
        count = max(nodes, min(self.params["tiles_per_node"] * nodes, min(width, height) ** 2 // 4))
        self.ratio = self.next_ratio(inputs, -(-count // nodes))
        shares = round_shares(count, nodes, self.ratio)
        edges, field = self.edges(inputs, shares)
        rects = edges.rects(inputs.size)
        effort = [field.total((r.x, r.y, r.x1, r.y1)) for r in rects]
        order = sorted(range(len(rects)), key=lambda i: (-effort[i], i))
        tiles = tuple(Tile(rects[i], None) for i in order)
        key = tuple(t.rect for t in tiles)
        self.serial += 1
        self.repeated = key in self.planned and self.planned[key][0] == self.serial - 1
        self.planned.pop(key, None)
        load, overhead = sum(effort), self.tile_overhead_ms()
        self.planned[key] = (self.serial, [shares[i] / sum(shares) * load + overhead for i in order])
        while len(self.planned) > KEPT_PLANS:
            del self.planned[next(iter(self.planned))]
        return Partition(tiles, pull=True)

    def tile_overhead_ms(self) -> float:
        """What a tile costs beyond its rect's load in the field (effort ms), counted in its
        planned effort: none here, the load field being last frame's measured tiles."""
        return 0.0

    def next_ratio(self, inputs: BalanceInput, rounds: int) -> float:
        """The ratio between rounds' shares for the next partition: 1 (equal tiles) while frames
        come one at a time — the timings are of the last partition made, every node starts the
        next frame at once — or without timings of a partition of ours; else :func:`round_ratio`
        of how far the tiles the timings are of were from their planned efforts (their round's
        share of the field's load, plus :meth:`tile_overhead_ms`): the estimate's error and what
        kept the damped edges from their targets. Its rects repeating the last but one's, the
        ratio stays."""
        made = self.planned.get(tuple(t.rect for t in inputs.timings))
        if made is None:
            return 1.0
        serial, planned = made
        if serial == self.serial:
            return self.ratio if self.repeated else 1.0
        return round_ratio(estimate_error(planned, [measured_ms(t) * speed_of(inputs.weights, t.node_id)
                                                    for t in inputs.timings]), rounds)
