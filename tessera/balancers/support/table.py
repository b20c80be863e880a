"""The load-weight table of seed 002 §3.2: a fine uniform grid of screen cells, each holding the
effort (ms at speed 1) last measured over it (pure; the balancer that owns it keeps it between
frames). Used by ``grid`` (median cut).

Every cell starts at weight 1 (per pixel). After a frame, each measured tile's effort is spread
over the cells under its rect; the part ``memory`` of it follows the shape the table already has
inside the rect, the rest is spread uniformly. ``memory`` = 0 is seed 002's plain spread (the
table then only knows last frame's per-tile averages); with ``memory`` > 0 the table keeps the
detail earlier partitions revealed — the "history of render times" §3.2 combines — so a tile's
time is fitted to a finer load map frame after frame (iterative proportional fitting), while the
uniform part lets load that moved show up again.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from tessera.balancers.base import TileTiming
from tessera.balancers.support.load import FLOOR, measured_ms, speed_of


def _overlaps(starts: np.ndarray, ends: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Length of each interval [start, end) (K,) inside each cell of ``edges`` (C+1,): (K, C)."""
    return np.clip(np.minimum(ends[:, None], edges[None, 1:]) - np.maximum(starts[:, None], edges[None, :-1]),
                   0.0, None)


def _cells(edges: np.ndarray, start: float, end: float) -> tuple[slice, np.ndarray]:
    """The cells of ``edges`` that [start, end) touches, and the length inside each."""
    first = max(int(np.searchsorted(edges, start, side="right")) - 1, 0)
    last = max(int(np.searchsorted(edges, end, side="left")), first + 1)
    cells = slice(first, min(last, len(edges) - 1))
    return cells, _overlaps(np.array([start]), np.array([end]), edges[cells.start:cells.stop + 1])[0]


class LoadTable:
    """Cells of about ``cell_px`` pixels over a ``size`` screen; ``values`` (rows, cols) effort."""

    def __init__(self, size: tuple[int, int], cell_px: int) -> None:
        width, height = size
        self.size, self.cell_px = size, cell_px
        self.xs = np.rint(np.linspace(0, width, max(1, width // cell_px) + 1))
        self.ys = np.rint(np.linspace(0, height, max(1, height // cell_px) + 1))
        self.cell_area = np.outer(np.diff(self.ys), np.diff(self.xs))
        self.values = self.cell_area.copy()

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape

    def update(self, timings: Sequence[TileTiming], weights: Mapping[int, float], memory: float,
               render_only: bool = False) -> None:
        """Spread each tile's effort over the cells under it (see the module docstring)."""
        width, height = self.size
        density = self.values / self.cell_area
        spread = np.zeros_like(self.values)
        coverage = np.zeros_like(self.values)
        measured = 0.0
        for timing in timings:
            x0, x1 = min(max(timing.rect.x, 0), width), min(max(timing.rect.x1, 0), width)
            y0, y1 = min(max(timing.rect.y, 0), height), min(max(timing.rect.y1, 0), height)
            if x1 <= x0 or y1 <= y0:
                continue
            (rows, across_y), (cols, across_x) = _cells(self.ys, y0, y1), _cells(self.xs, x0, x1)
            overlap = np.outer(across_y, across_x)
            local = float((overlap * density[rows, cols]).sum()) / float(overlap.sum())
            relative = density[rows, cols] / local if local > 0.0 else 1.0
            shape = overlap * ((1.0 - memory) + memory * relative)
            effort = measured_ms(timing, render_only) * speed_of(weights, timing.node_id)
            spread[rows, cols] += effort * shape / shape.sum()
            coverage[rows, cols] += overlap / self.cell_area[rows, cols]
            measured += effort
        coverage = np.minimum(coverage, 1.0)
        predicted = float((self.values * coverage).sum())
        if not coverage.any():
            return
        scale = measured / predicted if predicted > 0.0 and measured > 0.0 else 1.0
        values = spread + self.values * scale * (1.0 - coverage)
        mean = float(values.sum()) / values.size
        self.values = np.maximum(values, FLOOR * mean) if mean > 0.0 else self.cell_area.copy()

    def summed(self) -> np.ndarray:
        """(rows+1, cols+1) summed-area table of ``values``, zero first row and column."""
        table = np.zeros((self.values.shape[0] + 1, self.values.shape[1] + 1))
        table[1:, 1:] = self.values.cumsum(0).cumsum(1)
        return table
