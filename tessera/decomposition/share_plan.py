"""Sort-last data partitions on the coordinator (issue 10: database decomposition), sans-I/O.

A partition gives each connected node one share of the scene's chunks, sized by its weight (its
calibrated speed, seed 003 §1, as known when the partition is made). Nodes compute the shares
themselves from the same file (:mod:`tessera.decomposition.data_partition`, :mod:`node.scene.shares`), so a
partition travels as its version, each node's share index and the weights.

Every node joining or leaving makes a new partition, with the next version; each node is told
to load its share of it. Frames use only a partition every share of which is loaded
(:attr:`ShareBook.complete`); until then no frame starts (a frame started earlier was dropped when
the partition changed), and a frame is drawn from one partition's shares only: it is never torn.
Nodes that join or leave one after another make several partitions in a row, whose loads may end
in any order: a node's newest share counts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class SharePlan:
    """Partition ``version``: share i is held by node ``holders[i]`` (ascending ids), with weight
    ``weights[i]``."""

    version: int
    holders: tuple[int, ...]
    weights: tuple[float, ...]

    def index_of(self, node_id: int) -> int:
        return self.holders.index(node_id)


@dataclass
class ShareBook:
    """The newest partition (None: no node connected) and the partition version each node has
    loaded a share of."""

    plan: SharePlan | None = None
    loaded: dict[int, int] = field(default_factory=dict)
    _version: int = 0

    def repartition(self, weights: Mapping[int, float]) -> SharePlan | None:
        """A new partition over the nodes of ``weights`` (node id → weight > 0); None for none."""
        self._version += 1
        holders = tuple(sorted(weights))
        self.plan = SharePlan(self._version, holders, tuple(float(weights[n]) for n in holders)) if holders else None
        return self.plan

    def share_loaded(self, node_id: int, version: int) -> bool:
        """Node ``node_id`` holds its share of partition ``version`` now; True when that makes the
        newest partition complete. A share of an older partition than one it reported already (its
        loads end in any order) changes nothing: the newer share is still held."""
        was = self.complete
        self.loaded[node_id] = max(version, self.loaded.get(node_id, version))
        return self.complete and not was

    def forget(self, node_id: int) -> None:
        """The node left (its share goes with it)."""
        self.loaded.pop(node_id, None)

    @property
    def complete(self) -> bool:
        """Every share of the newest partition is loaded: frames may use it."""
        plan = self.plan
        return plan is not None and all(self.loaded.get(n) == plan.version for n in plan.holders)
