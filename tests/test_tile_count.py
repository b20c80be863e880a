"""Tiles a node held by the measured efficiency (tessera/balancers/support/tile_count.py, and
rotate's use of it; pure, no GL, no network)."""

from __future__ import annotations

import pytest

from bench.virtual_cluster import rect_sums, summed_area
from tessera.balancers.base import BalanceInput, Partition, TileTiming
from tessera.balancers.rotate import RotateBalancer
from tessera.balancers.rotate_predict import RotatePredictBalancer
from tessera.balancers.support.tile_count import (
    HISTORY,
    MIN_FRAMES,
    RETRY_FRAMES,
    SETTLE_FRAMES,
    TileCountLoop,
    frame_efficiency,
)
from tessera.geometry import Rect
from tests.test_balancers import corner_map

SIZE = (480, 270)
NODES = (1, 2, 3, 4)


def test_frame_efficiency_is_the_work_spread_over_the_busiest_node() -> None:
    rect = Rect(0, 0, 8, 8)
    timings = (TileTiming(rect, 1, 6.0, 2.0, 2.0), TileTiming(rect, 2, 5.0))
    assert frame_efficiency(timings, (1, 2), {}) == pytest.approx(15.0 / 2.0 / 10.0)
    assert frame_efficiency(timings, (1, 2, 3), {}) == pytest.approx(15.0 / 3.0 / 10.0)   # node 3 drew nothing
    # node 2 twice as fast: 10 + 10 ms of effort over 3 speed units, 20 / 3 / 10
    assert frame_efficiency(timings, (1, 2), {2: 2.0}) == pytest.approx(20.0 / 3.0 / 10.0)
    assert frame_efficiency((), (1, 2), {}) == 1.0


def settled(lowest: int = 3, highest: int = 5, target: float = 0.965) -> TileCountLoop:
    loop = TileCountLoop(lowest, highest, target, tau_ms=50.0)
    loop.wait(200.0)
    assert {loop.observe(0.5, lowest) for _ in range(SETTLE_FRAMES)} == {lowest}   # the edges settling
    return loop


def test_a_tile_more_while_under_the_target_one_less_well_above_it() -> None:
    loop = settled()
    counts = [loop.observe(0.94 + 0.002 * (i % 3), 3) for i in range(MIN_FRAMES)]
    assert counts == [3] * (MIN_FRAMES - 1) + [4]
    loop.wait(200.0)
    assert [loop.observe(0.95, 3) for _ in range(HISTORY)] == [4] * HISTORY   # frames of the old count
    assert [loop.observe(0.97 + 0.002 * (i % 3), 4) for i in range(3 * HISTORY)] == [4] * 3 * HISTORY
    # well above the target, but 3 was short (at frame SETTLE_FRAMES + MIN_FRAMES): it stays
    # until RETRY_FRAMES have gone
    while loop.frames < RETRY_FRAMES + SETTLE_FRAMES + MIN_FRAMES - 1:
        assert loop.observe(0.99, 4) == 4
    assert loop.observe(0.99, 4) == 3


def test_the_count_keeps_to_its_bounds_and_waits_for_the_edges() -> None:
    loop = TileCountLoop(3, 4, 0.965, tau_ms=50.0)
    assert [loop.observe(0.5, 3) for _ in range(3 * MIN_FRAMES)] == [3] * 3 * MIN_FRAMES   # not settled
    loop.wait(200.0)
    assert [loop.observe(0.5, 3) for _ in range(MIN_FRAMES)][-1] == 4
    loop.wait(200.0)
    assert {loop.observe(0.5 + 0.01 * (i % 2), 4) for i in range(3 * MIN_FRAMES)} == {4}   # the highest
    fixed = settled(target=0.0)
    assert {fixed.observe(0.5, 3) for _ in range(3 * MIN_FRAMES)} == {3}
    noisy = settled()   # a mean under the target by less than its standard error: no change
    assert {noisy.observe(0.995 if i % 2 else 0.925, 3) for i in range(HISTORY)} == {3}


def timed(partition: Partition, frame_nodes: tuple[int, ...]) -> tuple[TileTiming, ...]:
    """The corner map's exact cost of each tile, drawn in turn by ``frame_nodes``."""
    costs = rect_sums(summed_area(corner_map(SIZE)), partition.rects)
    return tuple(TileTiming(t.rect, frame_nodes[i % len(frame_nodes)], float(c))
                 for i, (t, c) in enumerate(zip(partition.tiles, costs, strict=True)))


def test_rotate_adds_a_round_of_tiles_when_frames_stay_uneven_placed_without_damping() -> None:
    """Frames drawn by three of four nodes (efficiency ≤ 0.75): once the edges settled, after
    :data:`SETTLE_FRAMES` + :data:`MIN_FRAMES` frames, 4 tiles a node; the partition of the new count is placed on the
    measured field at once (its tiles' loads within 8× of each other, the field being the last
    frame's tiles, uniform inside each), not damped from the equal split (the corner map's equal
    tiles differ 20×)."""
    balancer = RotateBalancer(efficiency_target=0.965)
    partition = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES))
    counts = []
    for frame in range(SETTLE_FRAMES + MIN_FRAMES + 3):
        partition = balancer.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=partition,
                                                    timings=timed(partition, (1, 2, 3)),
                                                    elapsed_ms=1000.0 if frame == 0 else 33.3))
        counts.append(len(partition.tiles))
        if len(partition.tiles) == 16:
            break
    assert counts == [12] * (SETTLE_FRAMES + MIN_FRAMES - 1) + [16]
    loads = rect_sums(summed_area(corner_map(SIZE)), partition.rects)
    assert max(loads) <= 8.0 * min(loads)
    fixed = RotateBalancer()   # rotate's default: the fixed count
    assert RotatePredictBalancer().params["efficiency_target"] == 0.0   # a frame's time decides: fixed
    partition = fixed.partition(BalanceInput(size=SIZE, node_ids=NODES))
    for _ in range(2 * MIN_FRAMES):
        partition = fixed.partition(BalanceInput(size=SIZE, node_ids=NODES, previous=partition,
                                                 timings=timed(partition, (1, 2, 3)), elapsed_ms=1000.0))
        assert len(partition.tiles) == 12
    with pytest.raises(ValueError, match="efficiency_target"):
        RotateBalancer(efficiency_target=1.0)
