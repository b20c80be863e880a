"""The load field predicted for the frame being partitioned, from its projected primitive groups
(seed 003 §3, DPBP) calibrated by the measured tile times (ours; pure). The ``*-predict``
balancers give it to their technique as its :class:`~tessera.balancers.support.load.LoadSource`.

Model: a tile's effort (measured busy ms × its node's speed weight, as everywhere) ≈ d + α·area +
β·G + γ·C, where G = the primitives inside the tile with each projected group's count spread
uniformly over its screen box, and C = the tile's pixels under group boxes (once per box:
fragments, overdraw). d is the per-tile overhead; α, β, γ ≥ 0 and d come from a non-negative
least-squares fit over the tiles of the last ``history`` measured frames, each tile against the
groups of the frame it was measured on (the predictor remembers the groups given with each
partition and matches timings to a partition by their rects; the most recent match wins, else
the current groups). Prediction: density α + Σₖ (β·wₖ/areaₖ + γ)·1[boxₖ] with this frame's boxes.
Correction (``correction`` = g): inside each last measured tile the density is scaled by
(measured / modelled effort of that tile)^g, clipped to [¼, 4], so where the model is off the
measurement still wins; with g = 1 a still camera reproduces the measured tiles exactly.

The field is a box per group and per group–tile overlap, swept by
:class:`~tessera.balancers.support.load.LoadField` in O(R log R).
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Iterable

import numpy as np

from tessera.balancers.base import BalanceInput, Partition, ProjectedGroups, TileTiming
from tessera.balancers.support.load import FLOOR, Field, LoadField, MeasuredLoad, measured_ms, rect_array, speed_of
from tessera.geometry import Rect

#: clip of the per-tile correction factor measured / modelled
CORRECTION_RANGE = (0.25, 4.0)
#: partitions whose groups are remembered (more than the frames in flight)
REMEMBERED_PARTITIONS = 8

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


def rect_key(rects: Iterable[Rect]) -> RectKey:
    """The set of ``rects`` as (x, y, w, h): a partition's key, found again from its timings."""
    return frozenset((r.x, r.y, r.w, r.h) for r in rects)


class LoadPredictor:
    """The fitted model and the groups remembered per partition (see the module docstring).

    Interface: :meth:`observe` (fit on a frame's timings), :meth:`field` (a load source: the
    prediction, else last frame's measured field), :meth:`predicted` (the prediction or None),
    :meth:`remember` (each partition made, with its groups). The fit runs once per
    ``BalanceInput``, when it is observed or its field first asked for. ``coef`` = (d ms,
    α ms/px, β ms/primitive, γ ms/px).
    """

    def __init__(self, history: int, correction: float) -> None:
        if history < 1:
            raise ValueError("history must be >= 1")
        if not 0.0 <= correction <= 1.0:
            raise ValueError("correction must be in [0, 1]")
        self.correction = correction
        self._partitions: deque[tuple[RectKey, ProjectedGroups | None]] = deque(maxlen=REMEMBERED_PARTITIONS)
        self._samples: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=history)
        self._size: tuple[int, int] | None = None
        self._fed: object = None
        self.coef = np.zeros(4)
        self._last: tuple[BalanceInput, Field | None] | None = None
        self._corrections: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 4)), np.zeros(0))
        self._measured = MeasuredLoad()

    @property
    def overhead_ms(self) -> float:
        """The fitted per-tile overhead d, effort ms."""
        return float(self.coef[0])

    def remember(self, partition: Partition, groups: ProjectedGroups | None) -> None:
        """Keep the groups ``partition`` was made with, to match its timings to them later."""
        self._partitions.append((rect_key(partition.rects), groups))

    def groups_for(self, timings: tuple[TileTiming, ...], current: ProjectedGroups | None) -> ProjectedGroups | None:
        """The groups of the partition the timings were measured on (most recent match), else ``current``."""
        key = rect_key(t.rect for t in timings)
        return next((groups for rects, groups in reversed(self._partitions) if rects == key), current)

    def observe(self, inputs: BalanceInput) -> None:
        """Fit on ``inputs``' timings now (a new sample when they are new) rather than when its field
        is first asked for."""
        self.predicted(inputs)

    def field(self, inputs: BalanceInput) -> Field:
        """The predicted field for ``inputs``, else last frame's measured one."""
        predicted = self.predicted(inputs)
        return predicted if predicted is not None else self._measured.field(inputs)

    def predicted(self, inputs: BalanceInput) -> Field | None:
        """The predicted field for ``inputs`` (its groups), or None without groups or timings;
        computed once per ``inputs``."""
        if self._last is None or self._last[0] is not inputs:
            self._last = (inputs, self._fit(inputs))
        return self._last[1]

    def _fit(self, inputs: BalanceInput) -> Field | None:
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
