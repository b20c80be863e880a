"""``rotate-predict`` — ours: seed 000 §4.3's tile rotation (``rotate``: k × N tiles of equal
estimated effort, pulled heaviest first) on the load field predicted for the frame being
partitioned (:class:`~tessera.balancers.support.predictor.LoadPredictor`), its edges moved as
``adaptive-predict``'s (:func:`~tessera.balancers.adaptive_predict.follow_camera`: with
``follow``, the camera's move is not damped). Tile shares stay equal and each tile's effort, for
the heaviest-first order, is read from the predicted field; with the fitted per-tile overhead
added, it is what the estimate's measured error, and so the ratio between rounds, compares
with the tiles' times.

Without groups, or before a fit, it is ``rotate``. Run time: with Lucy's 2 070 groups about 11 ms
per partition on the 2-core development machine.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from tessera.balancers.adaptive_predict import follow_camera
from tessera.balancers.base import BalanceInput, Partition
from tessera.balancers.rotate import RotateBalancer
from tessera.balancers.support.load import Field
from tessera.balancers.support.predictor import LoadPredictor
from tessera.balancers.support.strips import StripEdges


class RotatePredictBalancer(RotateBalancer):
    name = "rotate-predict"
    uses_groups = True
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "tau_ms": 50.0, "min_tile_px": 16, "tiles_per_node": 3, "history": 8, "correction": 1.0, "follow": True}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.predictor = LoadPredictor(self.params["history"], self.params["correction"])
        self.load = self.predictor

    def edges(self, inputs: BalanceInput, shares: Sequence[float]) -> tuple[StripEdges, Field]:
        """With ``follow``, :func:`follow_camera`'s edges where it gives some; ``rotate``'s otherwise."""
        followed = follow_camera(self.predictor, inputs, shares, self.params["tau_ms"],
                                 self.params["min_tile_px"]) if self.params["follow"] else None
        return followed if followed is not None else super().edges(inputs, shares)

    def tile_overhead_ms(self) -> float:
        """The fitted per-tile overhead d: a tile's predicted effort is d + its rect's load, so
        that the small tiles of the last round, which cost little but d, do not count as errors."""
        return self.predictor.overhead_ms

    def partition(self, inputs: BalanceInput) -> Partition:
        """``rotate``'s partition; every frame's timings are a sample of the fit."""
        self.predictor.observe(inputs)
        partition = super().partition(inputs)
        self.predictor.remember(partition, inputs.groups)
        return partition
