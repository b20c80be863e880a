"""Where a pulled frame's per-frame efficiency goes (issue 37): the same tiles at their measured
costs, scheduled two ways that no live scheduler can, beside what the frame got.

* ``efficiency_together``: the frame's tiles in their pull order (heaviest first by the balancer's
  estimate), each to the node that frees first, every node starting the frame at once — the
  heaviest-first pull without the stagger with which nodes come to a frame while the one before
  still ends (frames in flight);
* ``efficiency_sorted``: the same with the tiles sorted by their measured costs, heaviest first —
  the pull with a perfect estimate and no stagger;
* ``efficiency_best``: the best split of those tiles among the nodes (the least slowest-node busy
  time over every split, searched heaviest tile first; after :data:`SEARCH_STEPS` steps the best
  found): what no order of pulls can beat with this partition's tiles;
* ``stagger_ms``: the mean over a frame's nodes of when each began its first tile of it, after the
  first did (ms).

``efficiency`` ≤ ``efficiency_best``; the gap to ``efficiency_together`` is what the stagger costs,
from there to ``efficiency_sorted`` what the estimate's order costs, and the rest what pulling
whole tiles one after the other does against the best split."""

from __future__ import annotations

import heapq
from collections.abc import Mapping, Sequence

import numpy as np

from bench.virtual_cluster import FrameRecord

#: Steps of the best-split search per frame (12 tiles on 4 nodes take a few hundred).
SEARCH_STEPS = 20_000


def list_scheduled_ms(costs: Sequence[float], slowdowns: Sequence[float]) -> float:
    """The slowest node's busy ms when tiles of speed-1 ``costs`` (ms), in this order, each go to
    the node that frees first, every node (slowdown sᵢ: a tile takes cost × sᵢ) starting at 0."""
    free = [(0.0, i) for i in range(len(slowdowns))]
    for cost in costs:
        at, node = heapq.heappop(free)
        heapq.heappush(free, (at + cost * slowdowns[node], node))
    return max(at for at, _ in free)


def best_split_ms(costs: Sequence[float], slowdowns: Sequence[float], steps: int = SEARCH_STEPS) -> float:
    """The least slowest-node busy ms over the splits of tiles of speed-1 ``costs`` among nodes of
    ``slowdowns`` (depth first, heaviest tile first, pruned by the best so far; nodes equal in
    load and slowdown tried once); after ``steps`` steps the best found, at worst the heaviest-first
    list schedule's."""
    order = sorted(costs, reverse=True)
    best = [list_scheduled_ms(order, slowdowns)]
    floor = sum(order) / sum(1.0 / s for s in slowdowns)
    loads = [0.0] * len(slowdowns)
    left = [steps]

    def place(index: int) -> None:
        if index == len(order):
            best[0] = min(best[0], max(loads))
            return
        tried: set[tuple[float, float]] = set()
        for node, slowdown in enumerate(slowdowns):
            after = loads[node] + order[index] * slowdown
            if after >= best[0] or (loads[node], slowdown) in tried or left[0] <= 0 or best[0] <= floor * 1.0001:
                continue
            tried.add((loads[node], slowdown))
            left[0] -= 1
            loads[node] = after
            place(index + 1)
            loads[node] -= order[index] * slowdown

    place(0)
    return best[0]


def frame_loss(record: FrameRecord, slowdowns: Mapping[int, float]) -> dict[str, float]:
    """One frame's ``efficiency_together``, ``efficiency_sorted``, ``efficiency_best`` and ``stagger_ms`` (module
    docstring) from its tiles' spans, nodes and speed-1 costs."""
    speeds = [slowdowns[n] for n in sorted(slowdowns)]
    costs = [cost for _, _, cost in record.spans]
    firsts: dict[int, float] = {}
    for (begin, _, _), node in zip(record.spans, record.nodes, strict=True):
        firsts[node] = min(begin, firsts.get(node, begin))
    first = min(firsts.values())
    together = list_scheduled_ms(costs, speeds)
    ordered = list_scheduled_ms(sorted(costs, reverse=True), speeds)
    best = min(best_split_ms(costs, speeds), together, ordered, record.frame_ms)   # a search cut short: splits seen
    return {"efficiency_together": record.ideal_ms / together, "efficiency_sorted": record.ideal_ms / ordered,
            "efficiency_best": record.ideal_ms / best,
            "stagger_ms": float(np.mean([begin - first for begin in firsts.values()]))}


def rotation_loss(records: Sequence[FrameRecord], slowdowns: Mapping[int, float], skip: int) -> dict[str, float]:
    """The means of :func:`frame_loss` over the frames after the first ``skip``, and the worst
    frame's ``efficiency`` and ``efficiency_together``."""
    kept = [frame_loss(r, slowdowns) for r in records[skip:]]
    if not kept:
        raise ValueError(f"need more than {skip} frames, got {len(records)}")
    figures = {key: float(np.mean([k[key] for k in kept])) for key in kept[0]}
    return {**figures, "efficiency_worst": float(min(r.efficiency for r in records[skip:])),
            "efficiency_together_worst": float(min(k["efficiency_together"] for k in kept))}


def frame_trace(record: FrameRecord) -> dict[str, object]:
    """One frame as ``bench.balance --trace`` writes it: its camera, efficiency and, per node, when
    it began and ended its tiles of the frame (ms after the frame's first tile began), its busy
    ms and each of its tiles' busy ms in the order it drew them."""
    first = min(begin for begin, _, _ in record.spans)
    nodes: dict[str, dict[str, object]] = {}
    for (begin, end, _), node in sorted(zip(record.spans, record.nodes, strict=True)):
        row = nodes.setdefault(str(node), {"begin_ms": round(begin - first, 3), "tiles_ms": []})
        row["end_ms"] = round(end - first, 3)
        row["tiles_ms"].append(round(end - begin, 3))  # type: ignore[attr-defined]
    for row in nodes.values():
        row["busy_ms"] = round(sum(row["tiles_ms"]), 3)  # type: ignore[call-overload]
    return {"frame": record.frame_id, "camera": record.camera, "efficiency": round(record.efficiency, 4),
            "nodes": nodes}
