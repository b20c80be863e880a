"""Sort-first (seed 000 §4.2–4.3, the default mode): the screen cut into disjoint tiles by the
balancer, every node holding the whole scene; a frame is its tiles as the nodes sent them."""

from __future__ import annotations

from typing import Any

from tessera.decomposition.mode import DecompositionMode


class SortFirst(DecompositionMode):
    name = "sort-first"

    def describe(self) -> dict[str, Any]:
        return {"mode": self.name, "depth_strip": None, "partition": None}
