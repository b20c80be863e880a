"""``adaptive-fit`` — seed 000 §4.2 placed on seed 002 §3.2's load-weight table (our improvement).

Why: ``adaptive`` assumes effort uniform inside last frame's tiles. With few large tiles that
estimate is coarse: undamped, edges overshoot and oscillate; damped with the seed's 200 ms they
lag a moving camera (synthetic moving hot spot, 4–8 nodes: mean max/mean 1.13–1.76, goal 1.08).
Here the same strips→tiles edges are placed on a fine load table fitted to every frame's tile
times (:class:`tessera.balancers.table.LoadTable`, ``memory`` of the in-tile shape kept), which
locates load inside a tile after a few frames, so edges can follow with a shorter time constant.
Everything else (topology, node weights, damping law, fallbacks) is ``adaptive``'s.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.base import BalanceInput
from tessera.balancers.load import Field
from tessera.balancers.table import LoadTable


class AdaptiveFitBalancer(AdaptiveBalancer):
    name = "adaptive-fit"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "tau_ms": 50.0, "min_tile_px": 16, "cell_px": 4, "memory": 0.8}

    def __init__(self, **params: object) -> None:
        super().__init__(**params)
        self._table: LoadTable | None = None
        self._fed: object = None

    def validate_params(self) -> None:
        super().validate_params()
        if self.params["cell_px"] < 1:
            raise ValueError("cell_px must be >= 1")
        if not 0.0 <= self.params["memory"] < 1.0:
            raise ValueError("memory must be in [0, 1)")

    def field(self, inputs: BalanceInput) -> Field:
        """The table, fed each set of timings once (the coordinator may pass the same twice)."""
        if self._table is None or self._table.size != inputs.size:
            self._table, self._fed = LoadTable(inputs.size, self.params["cell_px"]), None
        if inputs.timings != self._fed:
            self._table.update(inputs.timings, inputs.weights, self.params["memory"])
            self._fed = inputs.timings
        return self._table
