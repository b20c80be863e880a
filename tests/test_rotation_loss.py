"""Where a pulled frame's efficiency goes (bench.rotation_loss, issue 37): the same tiles scheduled
from a common start and split at best, beside what the frame got; the per-frame trace."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import pytest

from bench.rotation_loss import best_split_ms, frame_loss, frame_trace, list_scheduled_ms, rotation_loss
from bench.virtual_cluster import FrameRecord, Phases, run_path
from tessera.balancers.base import BalanceInput, Balancer, Partition, Tile
from tessera.geometry import Rect
from tests.balance_support import cameras


def test_list_schedule_follows_the_order_and_the_best_split_does_not() -> None:
    """Tiles of 5, 4, 3, 3, 2, 1 ms on two nodes: heaviest first evens them at 9 ms, lightest first
    ends at 10; the best split is 9 whatever the order; a node twice as slow takes half as much."""
    assert list_scheduled_ms([5, 4, 3, 3, 2, 1], [1.0, 1.0]) == 9.0
    assert list_scheduled_ms([1, 2, 3, 3, 4, 5], [1.0, 1.0]) == 10.0
    assert best_split_ms([1, 2, 3, 3, 4, 5], [1.0, 1.0]) == 9.0
    assert best_split_ms([5, 4, 3, 3, 2, 1], [1.0, 2.0]) == 12.0   # 5+4+3 | (3+2+1) × 2
    assert best_split_ms([7.0], [1.0, 1.0, 1.0]) == 7.0


def record(spans: tuple[tuple[float, float, float], ...], nodes: tuple[int, ...],
           node_ms: dict[int, float]) -> FrameRecord:
    """A published frame of pulled tiles with these spans (begin, end, cost ms) drawn by ``nodes``."""
    work = sum(cost for _, _, cost in spans)
    ideal = work / len(node_ms)
    frame_ms = max(node_ms.values())
    partition = Partition(tuple(Tile(Rect(i, 0, 1, 1), None) for i in range(len(spans))), pull=True)
    return FrameRecord(1, 0, partition, node_ms, frame_ms, work, ideal, frame_ms / ideal, ideal / frame_ms, 0.0,
                       frame_ms, frame_ms, spans, nodes)


def test_a_staggered_frame_loses_what_a_common_start_does_not() -> None:
    """Pulled tiles of 4, 4, 2, 2 ms: node 1 came to the frame 2 ms before node 2 and drew 4 + 2 + 2
    while node 2 drew 4 (efficiency 6/8); from a common start the same order gives each 6 ms."""
    frame = record(((0.0, 4.0, 4.0), (2.0, 6.0, 4.0), (4.0, 6.0, 2.0), (6.0, 8.0, 2.0)), (1, 2, 1, 1),
                   {1: 8.0, 2: 4.0})
    assert frame.efficiency == 0.75
    loss = frame_loss(frame, {1: 1.0, 2: 1.0})
    assert loss == {"efficiency_together": 1.0, "efficiency_sorted": 1.0, "efficiency_best": 1.0, "stagger_ms": 1.0}
    trace = frame_trace(frame)
    assert trace["nodes"] == {"1": {"begin_ms": 0.0, "end_ms": 8.0, "tiles_ms": [4.0, 2.0, 2.0], "busy_ms": 8.0},
                              "2": {"begin_ms": 2.0, "end_ms": 6.0, "tiles_ms": [4.0], "busy_ms": 4.0}}


class Halves(Balancer):
    """Two pulled halves, every frame."""

    name = "halves"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {}

    def partition(self, inputs: BalanceInput) -> Partition:
        return Partition((Tile(Rect(0, 0, 50, 10), None), Tile(Rect(50, 0, 50, 10), None)), pull=True)


def test_the_virtual_cluster_records_who_drew_each_tile() -> None:
    """Pulled tiles of 6 and 2 ms, two frames in flight: node 2, done with the first frame's 2 ms
    tile at 2 ms, pulls the next frame's 6 ms one; node 1 comes to it at 6 ms, 4 ms later (2 ms a
    node); the frame after starts on both at once (frames go in pairs), so 1 ms a frame.
    Split or pulled from a common start, 6 + 2 is still 6 on one node."""
    def measure(camera: int, rects: Sequence[Rect]) -> list[Phases]:
        return [Phases(6.0), Phases(2.0)]

    records, _ = run_path(Halves(), measure, cameras(8), (100, 10), {1: 1.0, 2: 1.0}, in_flight=2)
    assert records[0].nodes == (1, 2) and records[1].nodes == (2, 1)
    loss = rotation_loss(records, {1: 1.0, 2: 1.0}, skip=2)
    assert [frame_loss(r, {1: 1.0, 2: 1.0})["stagger_ms"] for r in records[1:4]] == [2.0, 0.0, 2.0]
    assert loss["stagger_ms"] == pytest.approx(1.0)
    assert loss["efficiency_best"] == pytest.approx(4.0 / 6.0) == loss["efficiency_together"]
    assert loss["efficiency_sorted"] == pytest.approx(4.0 / 6.0)
    assert loss["efficiency_worst"] == pytest.approx(4.0 / 6.0)
