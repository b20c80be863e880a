"""``adaptive-predict``, ``rotate-predict`` and ``tree-predict`` — our improvement: seed 000 §4.2 /
§4.3 edges, and the binary cut tree of seed 002 and Equalizer, placed on a load field *predicted
for the frame being partitioned* from its projected primitive groups (seed 003 §3, DPBP),
calibrated by the measured tile times.

Why: ``adaptive`` and ``rotate`` spread each tile's measured time uniformly over the tile. On a real
scan the load sits where the model projects (Lucy: a narrow upright figure in mid-screen), so
computed edges overshoot; the timings arrive two frames late (frames in flight), and a moving
camera has moved the load by then. Here the load moves with the camera before any time is measured.

Model (:class:`LoadModel`): a tile's effort (measured busy ms × its node's speed weight, as
everywhere) ≈ d + α·area + β·G + γ·C, where G = the primitives inside the tile with each projected
group's count spread uniformly over its screen box, and C = the tile's pixels under group boxes
(once per box: fragments, overdraw). d is the per-tile overhead; α, β, γ ≥ 0 and d come from a
non-negative least-squares fit over the tiles of the last ``history`` measured frames, each tile
against the groups of the frame it was measured on (the balancer remembers the groups it was
given with each partition and matches timings to a partition by their rects; the most recent
match wins, else the current groups). Prediction: density α + Σₖ (β·wₖ/areaₖ + γ)·1[boxₖ] with
this frame's boxes. Correction (``correction`` = g): inside each last measured tile the density is
scaled by (measured / modelled effort of that tile)^g, clipped to [¼, 4], so where the model is off
the measurement still wins; with g = 1 a still camera reproduces the measured tiles exactly.

Edges: ``adaptive``'s strips→tiles placement and damping law, with two changes. The fitted
overhead d costs each node alike in effort, so with unequal speed weights node k's share of the
spatial load is wₖ·(L + N·d)/Σw − d rather than ∝ wₖ (push tiles only). With ``follow``, the part of
an edge's move that the camera alone causes — target on this frame's groups minus target on last
frame's groups, same fit and corrections — is not damped; damping (``tau_ms``, 50 ms: prediction
does not overshoot) acts on what the measurements changed. On a synthetic moving figure whose cost
is the model (tests/test_balancer_predict.py) that takes max/mean from 1.11 to 1.02; on Lucy, whose
chunk boxes are a coarse model (a box reaching behind the eye covers the screen), ``follow`` on and
off were within the measurement noise of each other (two runs each, orbit and fly-through).
Tree: ``tree-predict`` is ``eq-load``'s tree (nodes by speed weight, each region cut along its
longer side where the load reaches the left subtree's share) on the predicted field, undamped
(``damping`` 0: damping lags the camera; synthetic moving figure 1.017 at 0, 1.090 at Equalizer's
0.5; Lucy orbit 1.046 and 1.035, within the noise). It answers ``grid`` and ``eq-load``, which
spread a tile's time evenly over the tile: on Lucy the load is a thin column under the first cut,
so their cuts overshoot across it and oscillate.

Without groups, or before a fit, the balancers are their seed's (adaptive's field and edges,
eq-load's field).
Run time: with Lucy's 2 070 groups about 8 ms (adaptive-predict) and 11 ms (rotate-predict) per
partition on the 2-core development machine — the field holds a box per group and per group–tile
overlap, swept by :class:`tessera.balancers.load.LoadField` in O(R log R).
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.base import BalanceInput, Partition, ProjectedGroups, TileTiming
from tessera.balancers.eq_load import EqLoadBalancer
from tessera.balancers.load import FLOOR, Field, LoadField, measured_ms, rect_array, speed_of
from tessera.balancers.rotate import RotateBalancer
from tessera.balancers.static import minimum_for
from tessera.balancers.strips import StripEdges, damping_fraction, edges_of, place
from tessera.partition import strip_counts

#: clip of the per-tile correction factor measured / modelled
CORRECTION_RANGE = (0.25, 4.0)

RectKey = frozenset[tuple[int, int, int, int]]


def group_features(groups: ProjectedGroups | None, rects: np.ndarray) -> np.ndarray:
    """(T, 2) for each of ``rects`` (T, 4): the primitives of ``groups`` inside it (every group's
    weight spread uniformly over its box) and the pixels of it under group boxes (counted once per
    box: a proxy for fragments); zeros without groups."""
    if groups is None or len(groups.weights) == 0:
        return np.zeros((len(rects), 2))
    boxes = np.asarray(groups.boxes, dtype=np.float64).reshape(-1, 4)
    area = np.maximum((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]), 1e-9)
    across = [np.clip(np.minimum(rects[:, None, a + 2], boxes[None, :, a + 2])
                      - np.maximum(rects[:, None, a], boxes[None, :, a]), 0.0, None) for a in (0, 1)]
    overlap = across[0] * across[1]
    return np.column_stack([(overlap / area) @ np.asarray(groups.weights, dtype=np.float64), overlap.sum(axis=1)])


def nonnegative_fit(features: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Least-squares coefficients (F,) ≥ 0 of ``features`` (n, F) for ``target`` (n,): the best of
    the unconstrained fits on every subset of columns that comes out non-negative (F is small)."""
    scale = np.maximum(np.abs(features).max(axis=0), 1e-12)
    scaled = features / scale
    best, best_residual = np.zeros(features.shape[1]), float(target @ target)
    for count in range(1, features.shape[1] + 1):
        for subset in itertools.combinations(range(features.shape[1]), count):
            coef = np.linalg.lstsq(scaled[:, subset], target, rcond=None)[0]
            if (coef < 0.0).any():
                continue
            residual = float(np.sum((scaled[:, subset] @ coef - target) ** 2))
            if residual < best_residual:
                best = np.zeros(features.shape[1])
                best[list(subset)] = coef
                best_residual = residual
    return best / scale


class LoadModel:
    """The fitted model and the groups remembered per partition (see the module docstring)."""

    def __init__(self, history: int, correction: float) -> None:
        self.correction = correction
        self._partitions: deque[tuple[RectKey, ProjectedGroups | None]] = deque(maxlen=8)
        self._samples: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=history)
        self._size: tuple[int, int] | None = None
        self._fed: object = None
        self.coef = np.zeros(4)
        self._last: tuple[BalanceInput, Field | None] | None = None
        self._corrections: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 4)), np.zeros(0))

    def remember(self, partition: Partition, groups: ProjectedGroups | None) -> None:
        self._partitions.append((frozenset((t.rect.x, t.rect.y, t.rect.w, t.rect.h) for t in partition.tiles), groups))

    def groups_for(self, timings: tuple[TileTiming, ...], current: ProjectedGroups | None) -> ProjectedGroups | None:
        """The groups of the partition the timings were measured on (most recent match), else ``current``."""
        key = frozenset((t.rect.x, t.rect.y, t.rect.w, t.rect.h) for t in timings)
        return next((groups for rects, groups in reversed(self._partitions) if rects == key), current)

    def field(self, inputs: BalanceInput) -> Field | None:
        """The predicted field for ``inputs`` (its groups), or None without groups or timings;
        computed once per ``inputs``."""
        if self._last is None or self._last[0] is not inputs:
            self._last = (inputs, self._field(inputs))
        return self._last[1]

    def _field(self, inputs: BalanceInput) -> Field | None:
        if inputs.size != self._size:
            self._samples.clear()
            self._size, self._fed = inputs.size, None
        timings = tuple(t for t in inputs.timings if measured_ms(t) > 0.0)
        if inputs.groups is None or not timings:
            return None
        rects = rect_array(timings)
        area = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
        features = np.column_stack([np.ones(len(rects)), area,
                                    group_features(self.groups_for(timings, inputs.groups), rects)])
        effort = np.array([measured_ms(t) * speed_of(inputs.weights, t.node_id) for t in timings])
        if inputs.timings != self._fed:
            self._samples.append((features, effort))
            self._fed = inputs.timings
        self.coef = nonnegative_fit(np.vstack([f for f, _ in self._samples]),
                                    np.concatenate([e for _, e in self._samples]))
        if not (self.coef[1:] > 0.0).any():
            return None
        modelled = features[:, 1:] @ self.coef[1:]
        ratio = np.where(modelled > 0.0, (effort - self.coef[0]) / np.maximum(modelled, 1e-12), 1.0)
        self._corrections = (rects, np.clip(ratio, *CORRECTION_RANGE) ** self.correction - 1.0)
        return self.predict(inputs.size, inputs.groups)

    def previous_groups(self) -> ProjectedGroups | None:
        """The groups given with the last remembered partition."""
        return self._partitions[-1][1] if self._partitions else None

    def predict(self, size: tuple[int, int], groups: ProjectedGroups) -> Field:
        """The fitted density α + groups' density with ``groups``, × the corrections of the last
        measured tiles (a sum of boxes)."""
        width, height = size
        _, per_pixel, per_primitive, per_covered = self.coef
        boxes = np.asarray(groups.boxes, dtype=np.float64).reshape(-1, 4)
        group_density = per_covered + per_primitive * np.asarray(groups.weights, dtype=np.float64) / np.maximum(
            (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]), 1e-9)
        screen = np.array([[0.0, 0.0, width, height]])
        parts_boxes, parts_density = [screen, boxes], [np.array([per_pixel]), group_density]
        if self.correction > 0.0:
            rects, extra = self._corrections
            low = np.maximum(rects[:, None, :2], boxes[None, :, :2])
            high = np.minimum(rects[:, None, 2:], boxes[None, :, 2:])
            cut = np.concatenate([low, high], axis=2).reshape(-1, 4)
            cut_density = (extra[:, None] * group_density[None, :]).reshape(-1)
            keep = (cut[:, 2] > cut[:, 0]) & (cut[:, 3] > cut[:, 1]) & (cut_density != 0.0)
            parts_boxes += [rects, cut[keep]]
            parts_density += [per_pixel * extra, cut_density[keep]]
        density = np.concatenate(parts_density)
        floor = FLOOR * max(per_pixel, float(group_density.mean()) if group_density.size else 0.0, 1e-12)
        density[0] += floor
        return LoadField(np.vstack(parts_boxes), density)


class _Predicted:
    """Mixin: the seed balancer's edges, on :class:`LoadModel`'s field."""

    uses_groups = True
    params: dict[str, Any]

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)  # type: ignore[call-arg]
        self.model = LoadModel(self.params["history"], self.params["correction"])

    def validate_params(self) -> None:
        super().validate_params()  # type: ignore[misc]
        if self.params["history"] < 1:
            raise ValueError("history must be >= 1")
        if not 0.0 <= self.params["correction"] <= 1.0:
            raise ValueError("correction must be in [0, 1]")

    def field(self, inputs: BalanceInput) -> Field:
        predicted = self.model.field(inputs)
        return predicted if predicted is not None else super().field(inputs)  # type: ignore[misc]

    def edges(self, inputs: BalanceInput, shares: Sequence[float]) -> tuple[StripEdges, Field]:
        """``adaptive``'s damped edges, except that the move the camera alone causes is not damped:
        the old edges are first shifted by (target on this frame's groups − target on last frame's
        groups), both with the same fit and corrections; damping then acts on what the
        measurements changed."""
        predicted, before = self.model.field(inputs), self.model.previous_groups()
        previous, size = inputs.previous, inputs.size
        counts = strip_counts(len(shares), size)
        old = edges_of(previous.rects, counts, size) if previous is not None and inputs.previous_matches() else None
        if predicted is None or before is None or old is None or not self.params["follow"]:
            return super().edges(inputs, shares)  # type: ignore[misc]
        minimum = minimum_for(size, len(shares), self.params["min_tile_px"])
        now = place(predicted, size, counts, shares, None, 1.0, minimum)
        then = place(self.model.predict(size, before), size, counts, shares, None, 1.0, minimum)
        shifted = StripEdges(
            tuple(np.add(old.rows, np.subtract(now.rows, then.rows)).tolist()),
            tuple(tuple(np.add(o, np.subtract(n, t)).tolist()) for o, n, t in zip(old.cols, now.cols, then.cols,
                                                                                  strict=True)))
        fraction = damping_fraction(inputs.elapsed_ms, self.params["tau_ms"])
        return place(predicted, size, counts, shares, shifted, fraction, minimum), predicted

    def partition(self, inputs: BalanceInput) -> Partition:
        partition = super().partition(inputs)  # type: ignore[misc]
        self.model.remember(partition, inputs.groups)
        return partition


class AdaptivePredictBalancer(_Predicted, AdaptiveBalancer):
    name = "adaptive-predict"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "tau_ms": 50.0, "min_tile_px": 16, "history": 8, "correction": 1.0, "follow": True}

    def shares(self, inputs: BalanceInput, nodes: Sequence[int]) -> list[float]:
        """Node k's share of the predicted load Lₖ: the fitted per-tile overhead d costs every node
        alike in effort, so equal times (d + Lₖ) / wₖ need Lₖ = wₖ·(L + N·d) / Σw − d (≥ 5 % of
        the plain share wₖ·L / Σw); the plain shares wₖ without a prediction."""
        weights = np.array(super().shares(inputs, nodes))
        predicted = self.model.field(inputs)
        overhead = float(self.model.coef[0])
        if predicted is None or overhead <= 0.0:
            return weights.tolist()
        width, height = inputs.size
        load = predicted.total((0.0, 0.0, width, height))
        plain = weights * load / weights.sum()
        return np.maximum(weights * (load + len(nodes) * overhead) / weights.sum() - overhead, 0.05 * plain).tolist()


class RotatePredictBalancer(_Predicted, RotateBalancer):
    name = "rotate-predict"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "tau_ms": 50.0, "min_tile_px": 16, "tiles_per_node": 3, "history": 8, "correction": 1.0, "follow": True}


class TreePredictBalancer(_Predicted, EqLoadBalancer):
    name = "tree-predict"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "damping": 0.0, "min_tile_px": 16, "history": 8, "correction": 1.0}
