"""Tile rotation's shares by round (tessera/balancers/rotate.py; pure, no GL, no network): equal
tiles while frames come one at a time, tiles shrinking round by round once frames overlap, by as
much as the estimate's measured error allows."""

from __future__ import annotations

import pytest

from tessera.balancers.base import BalanceInput, Partition, TileTiming
from tessera.balancers.rotate import MIN_RATIO, RotateBalancer, estimate_error, round_ratio, round_shares

SIZE = (480, 270)
NODES = (1, 2, 3, 4)


def test_estimate_error_compares_shares() -> None:
    assert estimate_error([1.0, 2.0, 3.0], [2.0, 4.0, 6.0]) == pytest.approx(0.0)
    assert estimate_error([1.0, 1.0], [3.0, 1.0]) == pytest.approx(0.5)
    assert estimate_error([1.0, 1.0], [0.0, 0.0]) == 2.0


def test_round_ratio_follows_the_measured_error() -> None:
    assert round_ratio(0.0, 3) == MIN_RATIO == 0.15
    assert round_ratio(0.1, 3) == MIN_RATIO
    assert round_ratio(0.3, 3) == pytest.approx(0.3)   # a round's tile the error of one of the round before
    assert round_ratio(0.3, 4) == pytest.approx(0.3)
    assert round_ratio(1.2, 3) == 1.0      # off by more than a tile: equal tiles
    assert round_ratio(0.3, 1) == 1.0      # one tile per node
    assert round_shares(6, 2, 0.5) == [1.0, 1.0, 0.5, 0.5, 0.25, 0.25]


def timings_of(partition: Partition) -> tuple[TileTiming, ...]:
    """Exact timings on a screen whose cost grows along x, 1 to 2 ms per 1000 px; node 1 drew
    every tile."""
    def cost(x: float) -> float:
        return x + x * x / (2.0 * SIZE[0])

    return tuple(TileTiming(t.rect, 1, t.rect.h * (cost(t.rect.x1) - cost(t.rect.x)) / 1000.0)
                 for t in partition.tiles)


def test_tiles_shrink_by_round_only_while_frames_overlap() -> None:
    """Frames one at a time (the timings are of the last partition made): equal tiles. Frames
    overlapping (the newest timings are of an older partition: the nodes come to a frame
    staggered) and an exact estimate: each round's tiles the smallest share of the round's before
    (:data:`MIN_RATIO`; the last strip no thinner than the minimum tile), heaviest first, so the
    last tiles each node pulls are small enough to even out the stagger."""
    balancer = RotateBalancer()
    first = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES))
    second = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=first,
                                             timings=timings_of(first), elapsed_ms=1e6))
    one_at_a_time = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=second,
                                                    timings=timings_of(second), elapsed_ms=1e6))
    assert balancer.ratio == 1.0
    costs = [t.busy_ms for t in timings_of(one_at_a_time)]
    assert max(costs) <= 1.1 * min(costs)
    overlapping = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=one_at_a_time,
                                                  timings=timings_of(second), elapsed_ms=1e6))
    assert balancer.ratio == MIN_RATIO and overlapping.pull and len(overlapping.tiles) == 12
    costs = [t.busy_ms for t in timings_of(overlapping)]
    rounds = [sum(costs[i:i + 4]) for i in (0, 4, 8)]
    assert rounds[1] / rounds[0] == pytest.approx(MIN_RATIO, abs=0.06)
    assert rounds[2] < rounds[1]
    assert min(r.h for r in overlapping.rects[8:]) >= 16
    assert max(costs[8:]) < 0.1 * min(costs[:4])


def test_an_estimate_far_off_keeps_equal_tiles() -> None:
    """Timings of an older partition whose estimate was off by ≥ 1 (L1 of shares): equal tiles."""
    balancer = RotateBalancer()
    first = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES))
    second = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=first,
                                             timings=timings_of(first), elapsed_ms=1e6))
    skewed = tuple(TileTiming(t.rect, 1, 50.0 if i == 0 else 1.0) for i, t in enumerate(first.tiles))
    balancer.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=second, timings=skewed, elapsed_ms=1e6))
    assert balancer.ratio == 1.0
