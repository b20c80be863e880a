"""``tree-predict`` — ours: ``eq-load``'s cut tree (nodes by speed weight, each region cut along its
longer side where the load reaches the left subtree's share: seed 002's median cut, Equalizer's
load equalizer) on the load field predicted for the frame being partitioned
(:class:`~tessera.balancers.support.predictor.LoadPredictor`), undamped (``damping`` 0: damping
lags the camera; synthetic moving figure 1.017 at 0, 1.090 at Equalizer's 0.5; Lucy orbit 1.046
and 1.035, within the noise). It answers ``grid`` and ``eq-load``, which spread a tile's time
evenly over the tile: on Lucy the load is a thin column under the first cut, so their cuts
overshoot across it and oscillate.

The predictor fits when ``eq-load`` asks for a field: frames with timings and a previous
partition for these nodes and screen. Without groups, or before a fit, it is ``eq-load``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

from tessera.balancers.base import BalanceInput, Partition
from tessera.balancers.eq_load import EqLoadBalancer
from tessera.balancers.support.predictor import LoadPredictor


class TreePredictBalancer(EqLoadBalancer):
    name = "tree-predict"
    uses_groups = True
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "damping": 0.0, "min_tile_px": 16, "history": 8, "correction": 1.0}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.predictor = LoadPredictor(self.params["history"], self.params["correction"])
        self.load = self.predictor

    def partition(self, inputs: BalanceInput) -> Partition:
        partition = super().partition(inputs)
        self.predictor.remember(partition, inputs.groups)
        return partition
