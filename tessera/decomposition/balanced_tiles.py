"""The balanced screen partition of the sort-first and hybrid modes (seed 000 §4.2–4.3, seed 003):
the chosen balancer, fed the timings of the newest complete interactive frame, asked for each
frame's tiles, and the static split when it fails. Pure: the clock comes in as ``now`` (s)."""

from __future__ import annotations

from collections.abc import Sequence

from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups, TileTiming
from tessera.balancers.partition import check_exact_cover
from tessera.balancers.static import StaticBalancer


def tile_set(partition: Partition) -> frozenset[tuple[tuple[int, int, int, int], int | None]]:
    """The partition's (rect, node) pairs, order ignored (a pull list re-sorted is the same tiles)."""
    return frozenset(((t.rect.x, t.rect.y, t.rect.w, t.rect.h), t.node_id) for t in partition.tiles)


class BalancedTiles:
    """``balancer``'s partitions of a ``size`` = (w, h) frame: the last one (``last``), whether it
    moved the edges (``moving``), when it was made and the newest timings the balancer was fed.
    ``error``: why the balancer failed last (the static split was used), until taken."""

    def __init__(self, balancer: Balancer, size: tuple[int, int]) -> None:
        self.balancer = balancer
        self.size = size
        self.last: Partition | None = None
        self._before: Partition | None = None
        self._moving: bool | None = True
        self.error: str | None = None
        self._last_at: float | None = None
        self._timings: tuple[TileTiming, ...] = ()
        self._timings_frame_id = 0

    def set_balancer(self, balancer: Balancer) -> None:
        """Partition with ``balancer`` from the next frame (its history starts anew)."""
        self.balancer = balancer
        self.last, self._before, self._moving = None, None, True

    def partition(self, node_ids: Sequence[int], weights: dict[int, float], now: float,
                  groups: ProjectedGroups | None) -> Partition:
        """The balancer's partition over ``node_ids`` (ready, by id) with their speed ``weights`` and
        the frame's projected ``groups``; the static split if it fails (its reason in ``error``)."""
        elapsed_ms = 0.0 if self._last_at is None else (now - self._last_at) * 1000.0
        inputs = BalanceInput(size=self.size, node_ids=tuple(node_ids), previous=self.last, timings=self._timings,
                              weights=weights, elapsed_ms=elapsed_ms, groups=groups)
        try:
            partition = self.balancer.partition(inputs)
            check_exact_cover(partition.rects, self.size)
            strays = {t.node_id for t in partition.tiles if t.node_id is not None} - set(inputs.node_ids)
            if strays or (partition.pull and any(t.node_id is not None for t in partition.tiles)):
                raise ValueError(f"tiles assigned to nodes that are not ready: {sorted(strays)}")
        except Exception as exc:  # a balancer bug must not stop the frames: fall back to the static split
            partition = StaticBalancer().partition(inputs)
            self.error = f"{self.balancer.name}: {exc}"
        self.remember(partition)
        self._last_at = now
        return partition

    def remember(self, partition: Partition) -> None:
        """``partition`` was used (:attr:`moving` compares it with the one before)."""
        self._before, self.last = self.last, partition
        self._moving = None if self._before is not None else True

    @property
    def moving(self) -> bool:
        """The last partition differs from the one before (the edges still move), or it is the
        first; compared once per partition, when first asked (only while settle frames are owed).
        One tile, the whole frame on one node, has no edge to move: no settle frame follows it (a
        new session's scene that one node holds yet drew its first frame twice, 110-150 ms each of
        the 990k scan at 640x360 on the one node the other sessions' tiles waited at)."""
        if self.last is not None and len(self.last.tiles) == 1:
            return False
        if self._moving is None:
            assert self.last is not None and self._before is not None
            self._moving = self.last is not self._before and tile_set(self.last) != tile_set(self._before)
        return self._moving

    def take_timings(self, frame_id: int, timings: tuple[TileTiming, ...]) -> bool:
        """Interactive frame ``frame_id``'s tile timings feed the next partition unless newer ones
        did; True when taken."""
        if frame_id < self._timings_frame_id:
            return False
        self._timings, self._timings_frame_id = timings, frame_id
        return True
