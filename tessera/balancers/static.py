"""``static`` — the equal split of seed 000 §4.2 frame 0: the screen cut into N equal-area
tiles in the strips→tiles topology (Fig. 4.2), each node one tile, whatever was measured.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from tessera.balancers.base import BalanceInput, Balancer, Partition, Tile
from tessera.balancers.partition import equal_strip_partition


class StaticBalancer(Balancer):
    name = "static"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"min_tile_px": 16}

    def validate_params(self) -> None:
        if self.params["min_tile_px"] < 1:
            raise ValueError("min_tile_px must be >= 1")

    def partition(self, inputs: BalanceInput) -> Partition:
        nodes = sorted(inputs.node_ids)
        minimum = minimum_for(inputs.size, len(nodes), self.params["min_tile_px"])
        rects = equal_strip_partition(len(nodes), inputs.size, minimum)
        return Partition(tuple(Tile(rect, node) for rect, node in zip(rects, nodes, strict=True)))


def minimum_for(size: tuple[int, int], count: int, wanted: int) -> int:
    """The minimum tile side that still fits ``count`` tiles on ``size`` (≤ ``wanted``)."""
    return max(1, min(wanted, size[0] // count, size[1] // count))
