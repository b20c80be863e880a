"""Serial simulation of a balancer on synthetic per-pixel cost maps (pure, no GL, no clocks).

A tile's render time is the sum of a cost map over its rect divided by its node's speed; the
balancer is fed each frame's timings exactly as the coordinator feeds measured ones (previous
partition, per-tile timings, weights, elapsed time). Pull partitions are dispatched with
:func:`tessera.balancers.rotate.pull_schedule`. Used by the balancer tests and the benchmarks.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups, TileTiming, imbalance
from tessera.balancers.rotate import pull_schedule
from tessera.geometry import Rect


def summed_area(cost: np.ndarray) -> np.ndarray:
    """(H+1, W+1) summed-area table of an (H, W) cost map, zero first row and column."""
    table = np.zeros((cost.shape[0] + 1, cost.shape[1] + 1))
    table[1:, 1:] = cost.cumsum(0).cumsum(1)
    return table


def rect_sums(table: np.ndarray, rects: Sequence[Rect]) -> np.ndarray:
    """Sum of the cost map over each rect (R,), from its summed-area table."""
    r = np.array([[t.x, t.y, t.x1, t.y1] for t in rects], dtype=np.int64).reshape(-1, 4)
    return table[r[:, 3], r[:, 2]] - table[r[:, 1], r[:, 2]] - table[r[:, 3], r[:, 0]] + table[r[:, 1], r[:, 0]]


@dataclass(frozen=True)
class FrameResult:
    """One simulated frame: the partition used, each node's busy ms, max/mean imbalance, the frame
    time (slowest node) in ms and the efficiency Σ busy / (N × frame time)."""

    partition: Partition
    busy: dict[int, float]
    imbalance: float
    makespan: float
    efficiency: float


def render(partition: Partition, cost: np.ndarray, speeds: Mapping[int, float], node_ids: Sequence[int],
           jitter: np.ndarray | None = None) -> tuple[tuple[TileTiming, ...], dict[int, float], float]:
    """Tile timings, busy ms per node and makespan of one frame of ``partition`` on ``cost``;
    ``jitter`` (T,) optional factors on each tile's time (measurement noise)."""
    costs = rect_sums(summed_area(cost), partition.rects)
    if jitter is not None:
        costs = costs * jitter
    nodes = sorted(node_ids)
    if partition.pull:
        assignment, _ = pull_schedule(costs, [speeds.get(n, 1.0) for n in nodes])
        owners = [nodes[i] for i in assignment]
    else:
        owners = [t.node_id for t in partition.tiles if t.node_id is not None]
    timings = tuple(TileTiming(t.rect, owner, float(c) / speeds.get(owner, 1.0))
                    for t, owner, c in zip(partition.tiles, owners, costs, strict=True))
    busy = dict.fromkeys(nodes, 0.0)
    for timing in timings:
        busy[timing.node_id] += timing.render_ms
    return timings, busy, max(busy.values())


def run(balancer: Balancer, cost_at: Callable[[int], np.ndarray], node_ids: Sequence[int], frames: int,
        speeds: Mapping[int, float] | None = None, weights: Mapping[int, float] | None = None,
        dt_ms: float = 1000.0 / 30.0, groups_at: Callable[[int], ProjectedGroups] | None = None,
        nodes_at: Callable[[int], Sequence[int]] | None = None, noise: float = 0.0,
        seed: int = 0) -> list[FrameResult]:
    """Run ``frames`` frames; ``cost_at(i)`` is frame i's (H, W) cost map in ms per pixel at speed 1
    (its shape is the screen size), ``nodes_at(i)`` the nodes present (default ``node_ids``);
    each tile's time is multiplied by 1 + ``noise`` × a standard normal draw (seeded, ≥ 0)."""
    speeds = dict(speeds or {})
    rng = np.random.default_rng(seed)
    previous: Partition | None = None
    timings: tuple[TileTiming, ...] = ()
    results = []
    for frame in range(frames):
        cost = cost_at(frame)
        nodes = tuple(nodes_at(frame)) if nodes_at else tuple(node_ids)
        inputs = BalanceInput(size=(cost.shape[1], cost.shape[0]), node_ids=nodes, previous=previous,
                              timings=timings, weights=dict(weights or {}),
                              elapsed_ms=dt_ms if frame else 0.0,
                              groups=groups_at(frame) if groups_at else None)
        previous = balancer.partition(inputs)
        jitter = np.maximum(1.0 + noise * rng.standard_normal(len(previous.tiles)), 0.0) if noise else None
        timings, busy, makespan = render(previous, cost, speeds, nodes, jitter)
        efficiency = sum(busy.values()) / (len(busy) * makespan) if makespan > 0 else 1.0
        results.append(FrameResult(previous, busy, imbalance(busy), makespan, efficiency))
    return results
