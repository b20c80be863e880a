"""``adaptive-predict`` — ours: seed 000 §4.2's strips→tiles edges and damping (``adaptive``) placed
on the load field predicted for the frame being partitioned from its projected primitive groups
(:class:`~tessera.balancers.support.predictor.LoadPredictor`: seed 003 §3's DPBP, calibrated by
the measured tile times).

Why: ``adaptive`` and ``rotate`` spread each tile's measured time uniformly over the tile. On a real
scan the load sits where the model projects (Lucy: a narrow upright figure in mid-screen), so
computed edges overshoot; the timings arrive two frames late (frames in flight), and a moving
camera has moved the load by then. Here the load moves with the camera before any time is measured.

Edges: ``adaptive``'s strips→tiles placement and damping law, with two changes. The fitted
overhead d costs each node alike in effort, so with unequal speed weights node k's share of the
spatial load is wₖ·(L + N·d)/Σw − d rather than ∝ wₖ (push tiles only). With ``follow``, the part of
an edge's move that the camera alone causes — target on this frame's groups minus target on last
frame's groups, same fit and corrections — is not damped (:func:`follow_camera`); damping
(``tau_ms``, 50 ms: prediction does not overshoot) acts on what the measurements changed (what
``follow`` gains is in the design notes).

Without groups, or before a fit, it is ``adaptive`` (measured field and edges). Its run time grows
with the scene's primitive groups.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.base import BalanceInput, Partition
from tessera.balancers.partition import strip_counts
from tessera.balancers.static import minimum_for
from tessera.balancers.support.load import Field
from tessera.balancers.support.predictor import LoadPredictor
from tessera.balancers.support.strips import StripEdges, damping_fraction, edges_of, place


def follow_camera(predictor: LoadPredictor, inputs: BalanceInput, shares: Sequence[float], tau_ms: float,
                  min_tile_px: int) -> tuple[StripEdges, Field] | None:
    """``adaptive``'s damped edges for ``shares`` on the predicted field, except that the move the
    camera alone causes is not damped: the old edges are first shifted by (target on this frame's
    groups − target on last frame's groups), both with the same fit and corrections; damping then
    acts on what the measurements changed. None without a prediction, earlier groups or a previous
    partition for these nodes and screen in the strips→tiles topology."""
    predicted, before = predictor.predicted(inputs), predictor.previous_groups()
    previous, size = inputs.previous, inputs.size
    counts = strip_counts(len(shares), size)
    old = edges_of(previous.rects, counts, size) if previous is not None and inputs.previous_matches() else None
    if predicted is None or before is None or old is None:
        return None
    minimum = minimum_for(size, len(shares), min_tile_px)
    now = place(predicted, size, counts, shares, None, 1.0, minimum)
    then = place(predictor.predict(size, before), size, counts, shares, None, 1.0, minimum)
    shifted = StripEdges(
        tuple(np.add(old.rows, np.subtract(now.rows, then.rows)).tolist()),
        tuple(tuple(np.add(o, np.subtract(n, t)).tolist()) for o, n, t in zip(old.cols, now.cols, then.cols,
                                                                              strict=True)))
    fraction = damping_fraction(inputs.elapsed_ms, tau_ms)
    return place(predicted, size, counts, shares, shifted, fraction, minimum), predicted


class AdaptivePredictBalancer(AdaptiveBalancer):
    name = "adaptive-predict"
    uses_groups = True
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "tau_ms": 50.0, "min_tile_px": 16, "history": 8, "correction": 1.0, "follow": True}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.predictor = LoadPredictor(self.params["history"], self.params["correction"])
        self.load = self.predictor

    def shares(self, inputs: BalanceInput, nodes: Sequence[int]) -> list[float]:
        """Node k's share of the predicted load Lₖ: the fitted per-tile overhead d costs every node
        alike in effort, so equal times (d + Lₖ) / wₖ need Lₖ = wₖ·(L + N·d) / Σw − d (≥ 5 % of
        the plain share wₖ·L / Σw); the plain shares wₖ without a prediction."""
        weights = np.array(super().shares(inputs, nodes))
        predicted = self.predictor.predicted(inputs)
        overhead = self.predictor.overhead_ms
        if predicted is None or overhead <= 0.0:
            return weights.tolist()
        width, height = inputs.size
        load = predicted.total((0.0, 0.0, width, height))
        plain = weights * load / weights.sum()
        return np.maximum(weights * (load + len(nodes) * overhead) / weights.sum() - overhead, 0.05 * plain).tolist()

    def edges(self, inputs: BalanceInput, shares: Sequence[float]) -> tuple[StripEdges, Field]:
        """With ``follow``, :func:`follow_camera`'s edges where it gives some; ``adaptive``'s otherwise."""
        followed = follow_camera(self.predictor, inputs, shares, self.params["tau_ms"],
                                 self.params["min_tile_px"]) if self.params["follow"] else None
        return followed if followed is not None else super().edges(inputs, shares)

    def partition(self, inputs: BalanceInput) -> Partition:
        """``adaptive``'s partition; every frame's timings are a sample of the fit."""
        self.predictor.observe(inputs)
        partition = super().partition(inputs)
        self.predictor.remember(partition, inputs.groups)
        return partition
