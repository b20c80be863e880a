"""Which runs of triangles face wholly away from the eye (issue 32): their normal cones
(:mod:`node.scene.cones`) tested against the eye, so that a tile leaves out of its draw ranges the
chunks and coarse parts that back-face culling would drop whole (llvmpipe transforms and sets up every
back-facing triangle before it culls it). For batches drawn with back-face culling only
(:meth:`node.gl.lod_draws.LodDraws.back_culled`): the GL culls the same triangles, so the frame is
the same bit for bit.

A triangle faces away from an eye ``e`` when ``n · (p − e) > 0`` (``n`` its normal, ``p`` any of its
points). For every normal within ``α`` of the cone's axis ``a`` and every point within the sphere around
the run's box (centre ``c``, radius ``r``), that holds when the sphere lies inside the cone of apex
``e``, axis ``a`` and half-angle ``90° − α``: ``cos α · (d · a) − sin α · |d × a| ≥ r`` with
``d = c − e``. The test widens ``α`` by :data:`MARGIN` so that a triangle seen almost edge-on, which
the GL's rounding may find front-facing, is kept."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Radians the cones are widened by in the test (triangles within this of edge-on are kept).
MARGIN = 1e-3


def facing_away(cones: np.ndarray, boxes: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """(K,) bool: the runs with normal cones ``cones`` (K, 4) (axis, cos) and boxes ``boxes`` (K, 2, 3)
    of which every triangle faces away from ``eye`` (3,) (world space; a perspective camera's)."""
    cos = cones[:, 3].astype(np.float64)
    sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    cos_m = cos * math.cos(MARGIN) - sin * math.sin(MARGIN)
    sin_m = sin * math.cos(MARGIN) + cos * math.sin(MARGIN)
    lo, hi = boxes[:, 0].astype(np.float64), boxes[:, 1].astype(np.float64)
    d = (lo + hi) * 0.5 - np.asarray(eye, np.float64)
    radius = np.linalg.norm(hi - lo, axis=1) * (0.5 * (1.0 + 1e-6))
    axis = cones[:, :3].astype(np.float64)
    axis /= np.maximum(np.linalg.norm(axis, axis=1), 1e-300)[:, None]
    along = np.einsum("ij,ij->i", d, axis)
    across = np.linalg.norm(np.cross(d, axis), axis=1)
    return (cos_m > 0.0) & (cos_m * along - sin_m * across > radius)


#: Runs of triangles as :meth:`FacingAway.of` reads them: (cones (K, 4), boxes (K, 2, 3), batch (K,)).
Runs = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True, slots=True, eq=False)
class FacingAway:
    """A frame's test of the runs that face wholly away from ``eye`` (3,), among those of the batches
    ``backless`` (B,) bool marks (drawn with back-face culling; others are always kept): the scene's
    chunks (``chunk_runs``) and the coarse parts (``part_runs``) of its levels."""

    eye: np.ndarray
    backless: np.ndarray
    chunk_runs: Runs
    part_runs: Runs

    def chunks(self, ids: np.ndarray) -> np.ndarray:
        """(n,) bool which of the chunks ``ids`` (n,) int64 face away."""
        return self.of(ids, self.chunk_runs)

    def parts(self, ids: np.ndarray) -> np.ndarray:
        """(n,) bool which of the coarse parts ``ids`` (n,) int64 face away."""
        return self.of(ids, self.part_runs)

    def of(self, ids: np.ndarray, runs: Runs) -> np.ndarray:
        """(n,) bool which of the ``runs`` ``ids`` (n,) int64 face away."""
        cones, boxes, batch = runs
        away = np.zeros(ids.shape, bool)
        tested = np.flatnonzero(self.backless[batch[ids]] & (cones[ids, 3] > 0.0))
        if tested.size:
            rows = ids[tested]
            away[tested] = facing_away(cones[rows], boxes[rows], self.eye)
        return away
