"""Serial replay of a balancer over a camera path, with node times from a tile-cost function (pure).

The frame loop feeds a balancer exactly as the live coordinator (``server/service.py``) does:
the previous partition, the per-tile timings of the last *complete* frame, the node speed weights
from calibration, the elapsed time between partition calls (the path's ``dt_ms``) and, for
techniques that read them, the projected primitive groups. Tile costs come from ``measure(frame,
rects)`` — real renders in ``bench/balance.py``, a cost map in the tests — in milliseconds on a
speed-1 node; node i's times are multiplied by its slowdown sᵢ (sᵢ = 2: twice as slow, like
``python -m node --slowdown 2``).

Timing lag: the coordinator keeps 2 frames in flight, so when it partitions frame f the newest
complete frame is f − 2. ``lag`` L feeds frame f the timings of frame f − 1 − L (L = 1: as live;
L = 0: every frame sees its predecessor's timings). Frames with no complete frame yet get none.

Push partitions: a node's time is the sum of its tiles' costs × sᵢ. Pull partitions (tile
rotation): :func:`tessera.balancers.rotate.pull_schedule` hands the tiles out in list order to
the node free first, node speeds 1/sᵢ; the timings fed back name the node that pulled each tile.

Per frame: imbalance = max/mean of node times; frame time = the slowest node (the makespan for
pull); work = Σ tile costs at speed 1; ideal = work / Σ 1/sᵢ (the frame time if the work were
spread in proportion to node speed with no overhead); efficiency = ideal / frame time.

Pipelined: the frames also run through :class:`Pipeline`, the live coordinator's timeline with
L + 1 frames in flight, where a node that finished its part of a frame starts on the next one
(pushed tiles queue per node in frame order; pulled tiles go to whichever node is free first,
oldest frame first — seed 000 §4.3's "the fastest node is asked for a new frame"). Each record's
``done_ms`` is when its frame completed there and ``spans`` when each of its tiles ran;
:func:`summarize` reports ``efficiency_pipelined``: the work done between the last left-out
frame's completion and the one before the last completion, as ideal time, over that elapsed time
(a window between two completions, so work done ahead of it at the start is matched by work done
ahead of its end; never above 1). The timings fed back are
the per-frame ones above (for pull, the node that pulled a tile in the one-frame schedule; with
equal speeds the same costs).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups, TileTiming, imbalance
from tessera.balancers.rotate import pull_schedule
from tessera.geometry import Rect
from tessera.partition import check_exact_cover


@dataclass(frozen=True, slots=True)
class Phases:
    """A tile's measured phases on a speed-1 node, milliseconds."""

    render_ms: float
    readback_ms: float = 0.0
    encode_ms: float = 0.0

    @property
    def busy_ms(self) -> float:
        return self.render_ms + self.readback_ms + self.encode_ms


@dataclass(frozen=True)
class FrameRecord:
    """One replayed frame: its partition, each node's time (ms, slowdowns applied), frame time
    (ms), work (ms at speed 1), ideal frame time (ms), max/mean imbalance, efficiency, and when
    the frame completed in the pipelined timeline (ms from the first dispatch; NaN when not run)
    and each tile's (begin ms, end ms, speed-1 cost ms) there."""

    partition: Partition
    node_ms: dict[int, float]
    frame_ms: float
    work_ms: float
    ideal_ms: float
    imbalance: float
    efficiency: float
    done_ms: float = float("nan")
    spans: tuple[tuple[float, float, float], ...] = ()


#: ``measure(frame, rects)`` → each tile's phases at speed 1 (one frame's tiles measured together)
Measure = Callable[[int, Sequence[Rect]], Sequence[Phases]]


def dispatch(partition: Partition, phases: Sequence[Phases], node_ids: Sequence[int],
             slowdowns: Mapping[int, float]) -> tuple[tuple[TileTiming, ...], dict[int, float], float]:
    """Run one frame: the tile timings (each tile's phases × its node's slowdown, attributed to the
    node that rendered it), each node's busy ms and the frame time (ms)."""
    nodes = sorted(node_ids)
    owners: list[int | None]
    if partition.pull:
        costs = [p.busy_ms for p in phases]
        assignment, makespan = pull_schedule(costs, [1.0 / slowdowns.get(n, 1.0) for n in nodes])
        owners = [nodes[i] for i in assignment]
    else:
        owners = [t.node_id for t in partition.tiles]
    node_ms = dict.fromkeys(nodes, 0.0)
    timings = []
    for tile, owner, p in zip(partition.tiles, owners, phases, strict=True):
        if owner is None or owner not in node_ms:
            raise ValueError(f"tile {tile.rect} pushed to unknown node {owner}")
        s = slowdowns.get(owner, 1.0)
        timing = TileTiming(tile.rect, owner, p.render_ms * s, p.readback_ms * s, p.encode_ms * s)
        node_ms[owner] += timing.busy_ms
        timings.append(timing)
    frame_ms = makespan if partition.pull else max(node_ms.values())
    return tuple(timings), node_ms, frame_ms


class Pipeline:
    """The live coordinator's frame timeline: at most ``in_flight`` frames dispatched and not yet
    complete; each node works through its tiles in the order they reach it.

    ``node_ids`` with ``slowdowns`` sᵢ (a tile of speed-1 cost c takes c × sᵢ on node i).
    """

    def __init__(self, node_ids: Sequence[int], slowdowns: Mapping[int, float], in_flight: int) -> None:
        if in_flight < 1:
            raise ValueError("in_flight must be >= 1")
        self.nodes = sorted(node_ids)
        self.slowdown = np.array([float(slowdowns.get(n, 1.0)) for n in self.nodes])
        self.rank = np.argsort(self.slowdown, kind="stable")
        self.free_at = np.zeros(len(self.nodes))
        self.in_flight = in_flight
        self.done: list[float] = []
        self.started = 0.0

    def run(self, partition: Partition,
            phases: Sequence[Phases]) -> tuple[float, tuple[tuple[float, float, float], ...]]:
        """Dispatch the next frame (tiles with their speed-1 phases) once a slot is free; when it
        completes (ms from the first dispatch) and each tile's (begin, end, speed-1 cost) ms."""
        frame = len(self.done)
        if frame >= self.in_flight:
            self.started = max(self.started, sorted(self.done)[frame - self.in_flight])
        done = self.started
        spans = []
        for tile, p in zip(partition.tiles, phases, strict=True):
            if partition.pull:
                ready = np.maximum(self.free_at, self.started)
                node = int(self.rank[np.argmin(ready[self.rank])])
            else:
                node = self.nodes.index(tile.node_id)
            begin = max(float(self.free_at[node]), self.started)
            self.free_at[node] = begin + p.busy_ms * self.slowdown[node]
            spans.append((begin, float(self.free_at[node]), p.busy_ms))
            done = max(done, float(self.free_at[node]))
        self.done.append(done)
        return done, tuple(spans)


def ideal_ms(work_ms: float, slowdowns: Sequence[float]) -> float:
    """The frame time of ``work_ms`` (speed-1 ms) spread over nodes by speed: work / Σ 1/sᵢ."""
    return work_ms / sum(1.0 / s for s in slowdowns)


def replay(balancer: Balancer, frames: int, size: tuple[int, int], node_ids: Sequence[int], measure: Measure,
           slowdowns: Mapping[int, float] | None = None, weights: Mapping[int, float] | None = None,
           dt_ms: float = 1000.0 / 30.0, lag: int = 1,
           groups_at: Callable[[int], ProjectedGroups] | None = None,
           on_frame: Callable[[int, FrameRecord], None] | None = None) -> list[FrameRecord]:
    """Replay ``frames`` frames of ``balancer`` (see the module docstring); ``groups_at(f)`` is
    frame f's projected groups, passed only to balancers that use them. A partition that is not an
    exact cover of the screen raises ValueError (the live coordinator would fall back to static)."""
    if lag < 0:
        raise ValueError("lag must be >= 0")
    nodes = tuple(sorted(node_ids))
    slow = {n: float((slowdowns or {}).get(n, 1.0)) for n in nodes}
    if any(not s > 0.0 for s in slow.values()):
        raise ValueError("slowdowns must be > 0")
    history: list[tuple[TileTiming, ...]] = []
    pipeline = Pipeline(nodes, slow, lag + 1)
    previous: Partition | None = None
    records = []
    for frame in range(frames):
        source = frame - 1 - lag
        inputs = BalanceInput(size=size, node_ids=nodes, previous=previous,
                              timings=history[source] if source >= 0 else (), weights=dict(weights or {}),
                              elapsed_ms=dt_ms if frame else 0.0,
                              groups=groups_at(frame) if groups_at and balancer.uses_groups else None)
        partition = balancer.partition(inputs)
        check_exact_cover(partition.rects, size)
        phases = measure(frame, partition.rects)
        timings, node_ms, frame_ms = dispatch(partition, phases, nodes, slow)
        work = sum(p.busy_ms for p in phases)
        ideal = ideal_ms(work, list(slow.values()))
        record = FrameRecord(partition, node_ms, frame_ms, work, ideal, imbalance(node_ms),
                             ideal / frame_ms if frame_ms > 0.0 else 1.0, *pipeline.run(partition, phases))
        records.append(record)
        history.append(timings)
        previous = partition
        if on_frame is not None:
            on_frame(frame, record)
    return records


def tile_set(partition: Partition) -> frozenset[tuple[tuple[int, int, int, int], int | None]]:
    """The partition's (rect, node) pairs, order ignored (a pull list re-sorted is the same tiles)."""
    return frozenset(((t.rect.x, t.rect.y, t.rect.w, t.rect.h), t.node_id) for t in partition.tiles)


def summarize(records: Sequence[FrameRecord], skip: int = 10) -> dict[str, float | int]:
    """Figures over the frames after the first ``skip``: mean and 95th percentile of imbalance,
    mean efficiency, repartitions (frames whose tiles differ from the frame before's), frames,
    mean frame time and work (ms), and the pipelined efficiency and frame time over the window
    from the last left-out frame's completion to the last but one completion (frames are shown in
    order, so a frame counts as done when it and all before it are): the kept tiles' work inside
    the window as ideal ms (a tile's cost × its frame's ideal / work, the part of its span inside)
    over the window; NaN without ``done_ms`` or with fewer than 2 kept frames."""
    kept = list(records[skip:])
    if not kept:
        raise ValueError(f"need more than {skip} frames to summarize, got {len(records)}")
    ratios = np.array([r.imbalance for r in kept])
    shown = np.maximum.accumulate([r.done_ms for r in records])
    start = float(shown[skip - 1]) if skip else 0.0
    stop = float(shown[-2]) if len(kept) > 1 and np.isfinite(shown[-1]) else start
    elapsed = stop - start
    ideal_inside = sum(cost * r.ideal_ms / r.work_ms * max(min(end, stop) - max(begin, start), 0.0) / (end - begin)
                       for r in kept if r.work_ms > 0.0 for begin, end, cost in r.spans if end > begin)
    repartitions = sum(tile_set(records[i].partition) != tile_set(records[i - 1].partition)
                       for i in range(max(skip, 1), len(records)))
    return {"imbalance_mean": float(ratios.mean()), "imbalance_p95": float(np.percentile(ratios, 95)),
            "efficiency": float(np.mean([r.efficiency for r in kept])), "repartitions": int(repartitions),
            "frames": len(kept), "frame_ms": float(np.mean([r.frame_ms for r in kept])),
            "work_ms": float(np.mean([r.work_ms for r in kept])),
            "efficiency_pipelined": ideal_inside / elapsed if elapsed > 0.0 else float("nan"),
            "frame_ms_pipelined": elapsed / (len(kept) - 1) if elapsed > 0.0 else float("nan")}
