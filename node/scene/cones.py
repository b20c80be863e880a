"""Normal cones of runs of triangles (issue 32: culling clusters that face away from the eye, as
meshoptimizer's ``meshopt_computeClusterBounds``), worked out when a scene's levels are built
(:func:`node.scene.lod.build_lod`) and tested per tile by :func:`node.culling.cones.facing_away`. No GL,
no I/O.

A cone is a row ``(ax, ay, az, cos)`` float32: a unit axis and the cosine of the largest angle between
it and the unit normal (cross product of the edges, counter-clockwise: outwards on a closed solid) of
any of the run's triangles; ``cos`` ≤ 0 (:data:`NO_CONE`: a run without triangles or with normals a
half space wide) means no cone: the run is never culled. ``cos`` is rounded down after the axis was
rounded to float32, so every triangle's normal lies within the stored cone.
"""

from __future__ import annotations

import numpy as np

#: The cone of a run that is never culled.
NO_CONE = -1.0
#: Triangles whose normals are worked out at a time (bounds the memory: ~0.3 GB a block).
BLOCK_FACES = 1 << 21


def normal_cones(positions: np.ndarray, faces: np.ndarray, starts: np.ndarray,
                 end: int | None = None) -> np.ndarray:
    """(K, 4) float32 the normal cones of the runs of triangles ``faces[starts[k]:starts[k + 1]]``
    (the last up to ``end``, default all F) of ``faces`` (F, 3) over ``positions`` (V, 3). Triangles
    of zero area (no normal, no pixel) are left out of a cone."""
    starts = np.asarray(starts, np.int64)
    bounds = np.append(starts, len(faces) if end is None else end)
    cones = np.zeros((starts.size, 4), np.float32)
    cones[:, 3] = NO_CONE
    first = 0
    while first < starts.size:
        # Whole runs, about BLOCK_FACES triangles at a time (one run at least).
        last = max(first + 1, int(np.searchsorted(bounds, bounds[first] + BLOCK_FACES, side="right")) - 1)
        last = min(last, starts.size)
        cones[first:last] = _block_cones(positions, faces[bounds[first]:bounds[last]],
                                         bounds[first:last + 1] - bounds[first])
        first = last
    return cones


def _block_cones(positions: np.ndarray, faces: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """(K, 4) float32 the cones of runs [bounds[k], bounds[k + 1]) (K + 1,) of ``faces`` (n, 3)."""
    cones = np.zeros((bounds.size - 1, 4), np.float32)
    cones[:, 3] = NO_CONE
    counts = np.diff(bounds)
    filled = np.flatnonzero(counts > 0)
    if filled.size == 0:
        return cones
    corners = np.asarray(positions)[faces].astype(np.float64)   # (n, 3, 3)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1)
    area = length > 0.0
    normals /= np.where(area, length, 1.0)[:, None]
    sums = np.add.reduceat(normals, bounds[filled], axis=0)
    norms = np.linalg.norm(sums, axis=1)
    axes = (sums / np.where(norms > 0.0, norms, 1.0)[:, None]).astype(np.float32)
    # The angle from the stored (float32) axis, renormalised in float64 as the test reads it.
    stored = axes.astype(np.float64)
    stored /= np.maximum(np.linalg.norm(stored, axis=1), 1e-300)[:, None]
    owner = np.repeat(np.arange(filled.size), counts[filled])
    dots = np.einsum("ij,ij->i", normals, stored[owner])
    dots[~area] = 1.0
    cos = np.minimum.reduceat(dots, bounds[filled], axis=0)
    cos = np.nextafter(cos.astype(np.float32), np.float32(-np.inf))
    cones[filled, :3] = axes
    cones[filled, 3] = np.where((norms > 0.0) & (cos > 0.0), cos, NO_CONE)
    return cones


def merged_cones(cones: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(K, 4) float32 cones holding the cones (Q, 4) of the runs ``starts[k]`` … ``starts[k + 1] − 1``
    (the last to Q; none empty): around the mean of their axes, wide enough for the widest of them
    (angles add up), none where one of them has none."""
    starts = np.asarray(starts, np.int64)
    has = cones[:, 3] > 0.0
    axes = cones[:, :3].astype(np.float64)
    axes /= np.maximum(np.linalg.norm(axes, axis=1), 1e-300)[:, None]
    sums = np.add.reduceat(axes, starts, axis=0)
    norms = np.linalg.norm(sums, axis=1)
    merged = np.zeros((starts.size, 4), np.float32)
    merged[:, :3] = sums / np.where(norms > 0.0, norms, 1.0)[:, None]
    stored = merged[:, :3].astype(np.float64)
    stored /= np.maximum(np.linalg.norm(stored, axis=1), 1e-300)[:, None]
    owner = np.repeat(np.arange(starts.size), np.diff(np.append(starts, len(cones))))
    turn = np.arccos(np.clip(np.einsum("ij,ij->i", axes, stored[owner]), -1.0, 1.0))
    angle = np.maximum.reduceat(turn + np.arccos(np.clip(cones[:, 3].astype(np.float64), -1.0, 1.0)), starts)
    whole = np.logical_and.reduceat(has, starts) & (norms > 0.0) & (angle < np.pi / 2 - 1e-6)
    cos = np.nextafter(np.cos(angle + 1e-6).astype(np.float32), np.float32(-np.inf))
    merged[:, 3] = np.where(whole, cos, NO_CONE)
    return merged
