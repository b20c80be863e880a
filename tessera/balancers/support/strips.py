"""Edge placement in the strips→tiles topology of seed 000 §4.2 (Fig. 4.2), shared by
``adaptive`` and ``rotate`` (pure).

Strip edges are placed by accumulating per-scanline effort until each strip holds its share;
then, inside each strip, tile edges by accumulating per-column effort. Edges are damped
(§4.2, last paragraphs): the computed partition only gives each edge a velocity.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tessera.balancers.partition import clamp_edges, strips_to_rects
from tessera.balancers.support.load import Field
from tessera.geometry import Rect


@dataclass(frozen=True)
class StripEdges:
    """Integer edges: ``rows`` (S+1,) from 0 to height; ``cols[s]`` (T_s+1,) from 0 to width."""

    rows: tuple[int, ...]
    cols: tuple[tuple[int, ...], ...]

    def rects(self, size: tuple[int, int]) -> list[Rect]:
        """Row-major tile rects."""
        heights = np.diff(self.rows).tolist()
        widths = [np.diff(c).tolist() for c in self.cols]
        return strips_to_rects(size, heights, widths)


def edges_of(rects: Sequence[Rect], counts: Sequence[int], size: tuple[int, int]) -> StripEdges | None:
    """The strip edges of ``rects`` (any order) if they form the strips→tiles topology with
    ``counts`` tiles per strip on ``size``; None otherwise."""
    width, height = size
    ordered = sorted(rects, key=lambda r: (r.y, r.x))
    rows, cols, at = [0], [], 0
    for count in counts:
        strip = ordered[at:at + count]
        at += count
        if len(strip) != count or any(r.y != rows[-1] or r.h != strip[0].h for r in strip):
            return None
        xs = [0]
        for r in strip:
            if r.x != xs[-1]:
                return None
            xs.append(r.x1)
        if xs[-1] != width:
            return None
        rows.append(rows[-1] + strip[0].h)
        cols.append(tuple(xs))
    if at != len(ordered) or rows[-1] != height:
        return None
    return StripEdges(tuple(rows), tuple(cols))


def damping_fraction(elapsed_ms: float, tau_ms: float) -> float:
    """Fraction of the way an edge moves toward its computed position after ``elapsed_ms``.

    Exponential approach with time constant ``tau_ms``: an edge chasing a fixed target covers
    1 − e⁻¹ ≈ 63 % of the way in ``tau_ms`` whatever the frame rate (applying 1 − e^(−dt/τ) per
    frame composes to 1 − e^(−Σdt/τ)). ``tau_ms`` ≤ 0 jumps; ``elapsed_ms`` ≤ 0 holds still.
    """
    if tau_ms <= 0.0:
        return 1.0
    if not math.isfinite(elapsed_ms) or elapsed_ms <= 0.0:
        return 0.0
    return 1.0 - math.exp(-elapsed_ms / tau_ms)


def damp(old: Sequence[int] | None, target: np.ndarray, fraction: float) -> list[int]:
    """Integer edges moved ``fraction`` of the way from ``old`` toward ``target`` (floats); with no
    ``old`` edges, ``target`` rounded.

    A move that rounds to zero pixels becomes one pixel while the rounded target is elsewhere, so
    edges settle on the rounded target instead of stalling short of it.
    """
    if old is None:
        return np.rint(target).astype(np.int64).tolist()
    old_arr = np.asarray(old, dtype=np.float64)
    gap = np.asarray(target, dtype=np.float64) - old_arr
    step = np.rint(fraction * gap)
    if fraction > 0.0:
        step = np.where((step == 0.0) & (np.rint(gap) != 0.0), np.sign(gap), step)
    return (old_arr + step).astype(np.int64).tolist()


def _cuts(fractions: np.ndarray) -> np.ndarray:
    """Interior cut fractions of consecutive shares (K,) → (K−1,)."""
    return np.cumsum(fractions)[:-1] / fractions.sum()


def place(field: Field, size: tuple[int, int], counts: Sequence[int], shares: Sequence[float],
          old: StripEdges | None, fraction: float, minimum: int) -> StripEdges:
    """New damped edges: strips hold effort ∝ the sum of their tiles' ``shares`` (row-major, one
    per tile), tiles inside each strip ∝ their share; every tile at least ``minimum`` px. With no
    ``old`` edges the computed partition is taken as it is.

    Column targets are computed inside the strip as it will actually be rendered (after its edges
    were damped), from the exact overlap of that strip with last frame's tiles.
    """
    width, height = size
    share = np.asarray(shares, dtype=np.float64)
    bounds = np.cumsum([0, *counts])
    strip_share = np.array([share[a:b].sum() for a, b in itertools.pairwise(bounds)])
    rows_target = field.positions(1, (0.0, height), (0.0, width), _cuts(strip_share))
    rows_moved = damp(None if old is None else old.rows[1:-1], rows_target, fraction)
    heights = clamp_edges([0, *rows_moved, height], height, minimum)
    rows = np.cumsum([0, *heights]).tolist()
    cols = []
    for s, (a, b) in enumerate(itertools.pairwise(bounds)):
        cols_target = field.positions(0, (0.0, width), (rows[s], rows[s + 1]), _cuts(share[a:b]))
        cols_moved = damp(None if old is None else old.cols[s][1:-1], cols_target, fraction)
        widths = clamp_edges([0, *cols_moved, width], width, minimum)
        cols.append(tuple(np.cumsum([0, *widths]).tolist()))
    return StripEdges(tuple(rows), tuple(cols))
