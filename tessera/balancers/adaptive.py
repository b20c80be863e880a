"""``adaptive`` — seed 000 §4.2: time-based adaptive partition with damped edges.

N nodes, N tiles in the strips→tiles topology fixed by N (Fig. 4.2, :func:`strip_counts`);
tile k (row-major) belongs to the k-th node in id order, as in ``static``. Frame 0, and any frame
whose previous partition was made for other nodes or another screen size, is the equal split
(tile areas ∝ node weights); a previous partition of another shape is replaced by it, damped.
Afterwards last frame's tile times give an effort per pixel (uniform inside each tile); strip
edges move by accumulating per-scanline effort until each strip holds its share, then tile
edges inside each strip by per-column effort. Column effort is taken from the exact overlap of
the strip with last frame's tiles — the refinement §4.2 mentions and sets aside as giving similar
results; it costs no more here and also reads timings of a partition of another shape (the
frames in flight, or a switch from another balancer).

Heterogeneous nodes: effort is measured milliseconds × the node's speed weight
(``BalanceInput.weights``), and node k's tile is given effort ∝ its weight, so every node is
aimed at the same time. With all weights 1 this is the seed as written.

Damping: each edge moves toward its computed position by 1 − e^(−Δt/τ) of the way, Δt the real
time between the two frames (``BalanceInput.elapsed_ms``), τ = ``tau_ms`` (200 ms in the seed):
an edge chasing a fixed target covers 63 % of the way in τ at any frame rate (τ = 0: no damping).
Timings are busy time (render + readback + encode + send), what a node spends on its tile.

The load field comes from ``self.load`` (a :class:`~tessera.balancers.support.load.LoadSource`):
last frame's measured tiles here, the predicted field in ``adaptive-predict`` and ``rotate-predict``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from tessera.balancers.base import BalanceInput, Balancer, Partition, Tile
from tessera.balancers.partition import strip_counts
from tessera.balancers.static import minimum_for
from tessera.balancers.support.load import Field, LoadField, LoadSource, MeasuredLoad, speed_of
from tessera.balancers.support.strips import StripEdges, damping_fraction, edges_of, place


class AdaptiveBalancer(Balancer):
    name = "adaptive"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"tau_ms": 200.0, "min_tile_px": 16}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.load: LoadSource = MeasuredLoad()

    def validate_params(self) -> None:
        if self.params["tau_ms"] < 0.0:
            raise ValueError("tau_ms must be >= 0")
        if self.params["min_tile_px"] < 1:
            raise ValueError("min_tile_px must be >= 1")

    def shares(self, inputs: BalanceInput, nodes: Sequence[int]) -> list[float]:
        """Effort share of each tile, row-major: node k's speed weight."""
        return [speed_of(inputs.weights, node) for node in nodes]

    def edges(self, inputs: BalanceInput, shares: Sequence[float]) -> tuple[StripEdges, Field]:
        """Damped strip edges for ``len(shares)`` tiles, and the load field they were placed on."""
        size = inputs.size
        counts = strip_counts(len(shares), size)
        minimum = minimum_for(size, len(shares), self.params["min_tile_px"])
        uniform = LoadField.uniform(size)
        equal = place(uniform, size, counts, shares, None, 1.0, minimum)
        if inputs.previous is None or not inputs.previous_matches():
            return equal, uniform
        old = edges_of(inputs.previous.rects, counts, size) or equal
        if not inputs.timings:
            return old, uniform
        field = self.load.field(inputs)
        fraction = damping_fraction(inputs.elapsed_ms, self.params["tau_ms"])
        return place(field, size, counts, shares, old, fraction, minimum), field

    def partition(self, inputs: BalanceInput) -> Partition:
        nodes = sorted(inputs.node_ids)
        edges, _ = self.edges(inputs, self.shares(inputs, nodes))
        return Partition(tuple(Tile(rect, node) for rect, node in zip(edges.rects(inputs.size), nodes, strict=True)))
