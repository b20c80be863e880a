"""Last frame's measured load as a screen-space field, the area sweep over it, and where a
balancer's field comes from (pure).

Shared by the time-based balancers (seed 000 §4.2 ``adaptive``/``rotate``, ``eq-load``, and
``hetero`` when no primitive groups are given). Every measured tile spreads its *effort* uniformly
over its rect — the "effort is uniform inside a tile" assumption of seed 000 §4.2. Effort is a
tile's measured milliseconds times the speed weight of the node that rendered it, i.e. the
milliseconds a speed-1 node would have needed, so tiles measured on nodes of different speeds
are comparable. The load inside any band of the screen is then piecewise linear along an axis,
and the position where it reaches a fraction of a region's load is found exactly.

A technique is given its field by a :class:`LoadSource`: :class:`MeasuredLoad` (the seeds'), or
:class:`tessera.balancers.support.predictor.LoadPredictor` (the ``*-predict`` balancers').
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from tessera.balancers.base import BalanceInput, TileTiming

#: density added everywhere (relative to the mean) so cumulative load is strictly increasing
FLOOR = 1e-6


def measured_ms(timing: TileTiming, render_only: bool = False) -> float:
    """The milliseconds a balancer counts for a tile: busy time, or render time alone."""
    value = timing.render_ms if render_only else timing.busy_ms
    return value if np.isfinite(value) and value > 0.0 else 0.0


def speed_of(weights: Mapping[int, float], node_id: int) -> float:
    """A node's speed weight; missing, non-finite or non-positive weights count as 1."""
    value = float(weights.get(node_id, 1.0))
    return value if np.isfinite(value) and value > 0.0 else 1.0


def rect_array(timings: Sequence[TileTiming]) -> np.ndarray:
    """(T, 4) float64 x0, y0, x1, y1 of the timings' rects."""
    return np.array([[t.rect.x, t.rect.y, t.rect.x1, t.rect.y1] for t in timings], dtype=np.float64).reshape(-1, 4)


def node_times(timings: Sequence[TileTiming], render_only: bool = False) -> dict[int, float]:
    """Measured milliseconds per node over a frame's tiles."""
    out: dict[int, float] = {}
    for timing in timings:
        out[timing.node_id] = out.get(timing.node_id, 0.0) + measured_ms(timing, render_only)
    return out


class Field(Protocol):
    """Where the effort of a frame lies on the screen (pixel coordinates, effort ms)."""

    def total(self, box: tuple[float, float, float, float]) -> float:
        """Load inside ``box`` = (x0, y0, x1, y1)."""

    def positions(self, axis: int, span: tuple[float, float], band: tuple[float, float],
                  fractions: Sequence[float] | np.ndarray) -> np.ndarray:
        """Area sweep: where, along ``axis`` (0 = x, 1 = y) inside ``span`` × ``band``, the load from
        span[0] reaches each of ``fractions`` (K,) of the region's load; float positions (K,)."""


@dataclass(frozen=True)
class LoadField:
    """Piecewise-constant effort density: the sum of R axis-aligned boxes.

    ``boxes``: (R, 4) float64 pixel coordinates x0, y0, x1, y1; ``density``: (R,) effort
    milliseconds per pixel, summing to ≥ 0 everywhere. From timings, box 0 covers the whole screen
    (unmeasured area and the floor). R may be thousands (predicted fields: a box per primitive
    group and per group–tile overlap), hence the sorted sweep.
    """

    boxes: np.ndarray
    density: np.ndarray
    _orders: dict[int, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def uniform(cls, size: tuple[int, int]) -> LoadField:
        width, height = size
        return cls(np.array([[0.0, 0.0, width, height]]), np.ones(1))

    @classmethod
    def from_timings(cls, size: tuple[int, int], timings: Sequence[TileTiming],
                     weights: Mapping[int, float], render_only: bool = False) -> LoadField:
        """The field of last frame's tiles (clipped to the screen); unmeasured area gets the mean
        measured density, so a missing tile (dead node) neither attracts nor repels edges."""
        width, height = size
        rects = rect_array(timings)
        effort = np.array([measured_ms(t, render_only) * speed_of(weights, t.node_id)
                           for t in timings], dtype=np.float64)
        if rects.size == 0:
            return cls.uniform(size)
        rects = np.clip(rects, 0.0, [width, height, width, height])
        area = (rects[:, 2] - rects[:, 0]) * (rects[:, 3] - rects[:, 1])
        keep = area > 0.0
        rects, effort, area = rects[keep], effort[keep], area[keep]
        covered = min(float(area.sum()), float(width * height))
        if covered <= 0.0 or effort.sum() <= 0.0:
            return cls.uniform(size)
        mean = float(effort.sum()) / covered
        fill = mean if covered < width * height else 0.0
        screen = np.array([[0.0, 0.0, width, height]])
        return cls(np.vstack([screen, rects]),
                   np.concatenate([[fill + FLOOR * mean], effort / area - fill]))

    def total(self, box: tuple[float, float, float, float]) -> float:
        b = self.boxes
        across_x = np.clip(np.minimum(b[:, 2], box[2]) - np.maximum(b[:, 0], box[0]), 0.0, None)
        across_y = np.clip(np.minimum(b[:, 3], box[3]) - np.maximum(b[:, 1], box[1]), 0.0, None)
        return float((across_x * across_y) @ self.density)

    def positions(self, axis: int, span: tuple[float, float], band: tuple[float, float],
                  fractions: Sequence[float] | np.ndarray) -> np.ndarray:
        """The sweep over the boxes' start and end events sorted along ``axis``: O(R log R), the
        sort done once per axis (clipping to a span keeps the order)."""
        lo, hi = span
        b = self.boxes
        across = np.clip(np.minimum(b[:, 3 - axis], band[1]) - np.maximum(b[:, 1 - axis], band[0]), 0.0, None)
        slope = self.density * across
        events = np.concatenate([b[:, axis], b[:, axis + 2]])
        if axis not in self._orders:
            self._orders[axis] = np.argsort(events, kind="stable")
        order = self._orders[axis]
        at = np.concatenate([[lo], np.clip(events[order], lo, hi), [hi]])
        rate = np.concatenate([[0.0], np.cumsum(np.concatenate([slope, -slope])[order])])
        load = np.maximum.accumulate(np.concatenate([[0.0], np.cumsum(np.maximum(rate, 0.0) * np.diff(at))]))
        wanted = np.asarray(fractions, dtype=np.float64)
        if load[-1] <= 0.0:
            return lo + wanted * (hi - lo)
        return np.interp(wanted * load[-1], load, at)


class LoadSource(Protocol):
    """Where a balancer's load field comes from."""

    def field(self, inputs: BalanceInput) -> Field:
        """The load field to place ``inputs``' partition on."""


class MeasuredLoad:
    """Last frame's tiles, each tile's effort spread uniformly over it (seed 000 §4.2)."""

    def field(self, inputs: BalanceInput) -> Field:
        return LoadField.from_timings(inputs.size, inputs.timings, inputs.weights)
