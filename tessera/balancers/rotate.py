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
pulls) get effort ∝ ratioʳ, the smallest ratio in [½, 1] whose last tile still covers the error
e of a node's earlier ones (:func:`round_ratio`; ½ is factoring's halving), e measured when a
partition's timings come back (:func:`estimate_error`). Equal tiles (ratio 1) while
frames come one at a time (the timings are of the last partition made: every node starts the
next frame together, and equal tiles settle fastest), and until an estimate has been checked.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.base import BalanceInput, Partition, Tile
from tessera.balancers.support.load import measured_ms, speed_of
from tessera.geometry import Rect

#: Partitions whose tiles' predicted efforts are kept until their timings come back (frames in flight).
KEPT_PREDICTIONS = 8
#: The smallest ratio between successive rounds' shares: factoring's halving.
MIN_RATIO = 0.5


def estimate_error(predicted: Sequence[float], measured: Sequence[float]) -> float:
    """How far tiles' measured times (ms) were from their predicted efforts (ms): the L1 distance
    of the two as shares of their totals, 0 (exact) … 2; 2 when either total is not positive."""
    p_total, m_total = sum(predicted), sum(measured)
    if not (p_total > 0.0 and m_total > 0.0):
        return 2.0
    return sum(abs(p / p_total - m / m_total) for p, m in zip(predicted, measured, strict=True))


def round_ratio(error: float, rounds: int) -> float:
    """The ratio r between successive rounds' tile shares: the smallest in [:data:`MIN_RATIO`, 1]
    whose last round still covers the ``error`` (a relative error) of a node's earlier tiles,
    r^(rounds − 1) ≥ error × Σ_{j < rounds − 1} rʲ; 1 with one round or when none does."""
    if rounds < 2:
        return 1.0

    def covers(r: float) -> bool:
        return r ** (rounds - 1) >= error * sum(r ** j for j in range(rounds - 1))

    if covers(MIN_RATIO):
        return MIN_RATIO
    if not covers(1.0):
        return 1.0
    low, high = MIN_RATIO, 1.0
    for _ in range(30):
        middle = (low + high) / 2.0
        low, high = (low, middle) if covers(middle) else (middle, high)
    return high


def round_shares(count: int, nodes: int, ratio: float) -> list[float]:
    """Effort share of each of ``count`` tiles pulled by ``nodes`` nodes (relative, row-major):
    tile i is in round i // ``nodes`` and gets ``ratio`` to that power."""
    return [ratio ** (i // nodes) for i in range(count)]


class RotateBalancer(AdaptiveBalancer):
    name = "rotate"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"tau_ms": 200.0, "min_tile_px": 16, "tiles_per_node": 3}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        #: the last partitions' rects → (serial number, their tiles' predicted efforts in ms)
        self.predictions: dict[tuple[Rect, ...], tuple[int, list[float]]] = {}
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
        edges, field = self.edges(inputs, round_shares(count, nodes, self.ratio))
        rects = edges.rects(inputs.size)
        effort = [field.total((r.x, r.y, r.x1, r.y1)) for r in rects]
        order = sorted(range(len(rects)), key=lambda i: (-effort[i], i))
        tiles = tuple(Tile(rects[i], None) for i in order)
        key = tuple(t.rect for t in tiles)
        self.serial += 1
        self.repeated = key in self.predictions and self.predictions[key][0] == self.serial - 1
        self.predictions.pop(key, None)
        self.predictions[key] = (self.serial, [effort[i] for i in order])
        while len(self.predictions) > KEPT_PREDICTIONS:
            del self.predictions[next(iter(self.predictions))]
        return Partition(tiles, pull=True)

    def next_ratio(self, inputs: BalanceInput, rounds: int) -> float:
        """The ratio between rounds' shares for the next partition: 1 (equal tiles) while frames
        come one at a time — the timings are of the last partition made, every node starts the
        next frame at once — or without timings of a partition of ours; else :func:`round_ratio`
        of the error of the partition the timings are of. Its rects repeating the last but one's,
        the ratio stays."""
        made = self.predictions.get(tuple(t.rect for t in inputs.timings))
        if made is None:
            return 1.0
        serial, predicted = made
        if serial == self.serial:
            return self.ratio if self.repeated else 1.0
        return round_ratio(estimate_error(predicted, [measured_ms(t) * speed_of(inputs.weights, t.node_id)
                                                      for t in inputs.timings]), rounds)
