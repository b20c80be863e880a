"""Last frame's measured load as a screen-space field, and the area sweep over it (pure).

Shared by the time-based balancers (seed 000 §4.2 ``adaptive``/``rotate``, ``eq-load``, and
``hetero`` when no primitive groups are given). Every measured tile spreads its *effort* uniformly
over its rect — the "effort is uniform inside a tile" assumption of seed 000 §4.2. Effort is a
tile's measured milliseconds times the speed weight of the node that rendered it, i.e. the
milliseconds a speed-1 node would have needed, so tiles measured on nodes of different speeds
are comparable. The load inside any band of the screen is then piecewise linear along an axis,
and the position where it reaches a fraction of a region's load is found exactly.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tessera.balancers.base import TileTiming

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
    milliseconds per pixel. Box 0 covers the whole screen (unmeasured area and the floor).
    """

    boxes: np.ndarray
    density: np.ndarray

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
        rects = np.array([[t.rect.x, t.rect.y, t.rect.x1, t.rect.y1] for t in timings], dtype=np.float64)
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

    def _axis(self, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(start, end) along ``axis`` (0 = x, 1 = y) and (start, end) across it."""
        b = self.boxes
        return (b[:, 0], b[:, 2], b[:, 1], b[:, 3]) if axis == 0 else (b[:, 1], b[:, 3], b[:, 0], b[:, 2])

    def cumulative(self, axis: int, band: tuple[float, float], positions: np.ndarray) -> np.ndarray:
        """Load of the band [band0, band1) across ``axis`` from 0 to each of ``positions`` (P,)."""
        a0, a1, c0, c1 = self._axis(axis)
        across = np.clip(np.minimum(c1, band[1]) - np.maximum(c0, band[0]), 0.0, None)
        along = np.clip(np.asarray(positions, dtype=np.float64)[:, None] - a0[None, :], 0.0, (a1 - a0)[None, :])
        return along @ (self.density * across)

    def total(self, box: tuple[float, float, float, float]) -> float:
        ends = self.cumulative(0, (box[1], box[3]), np.array([box[0], box[2]]))
        return float(ends[1] - ends[0])

    def positions(self, axis: int, span: tuple[float, float], band: tuple[float, float],
                  fractions: Sequence[float] | np.ndarray) -> np.ndarray:
        lo, hi = span
        a0, a1, _, _ = self._axis(axis)
        breaks = np.unique(np.concatenate([a0, a1, [lo, hi]]))
        breaks = breaks[(breaks >= lo) & (breaks <= hi)]
        load = self.cumulative(axis, band, breaks)
        load -= load[0]
        if load[-1] <= 0.0:
            return lo + np.asarray(fractions, dtype=np.float64) * (hi - lo)
        return np.interp(np.asarray(fractions, dtype=np.float64) * load[-1], load, breaks)
