"""A loaded scene (:class:`SceneData`): batches in draw order, split into octree chunks at load
(seed 002 §3.4, :mod:`node.scene.chunks`), with the bounds and primitive groups a node reports.
No GL here."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.scene.chunks import PrimitiveGroups, SceneChunks, split_batches
from node.scene.mesh import MeshBatch, SceneError
from node.scene.octree import DEFAULT_FACE_LIMIT


@dataclass(frozen=True, eq=False)
class SceneData:
    """A loaded scene: batches in draw order (opaque first), world ``bounds`` (2, 3) float64, its
    ``chunks`` (batches over the face limit are split; their faces are in chunk order) and the
    primitive ``groups`` sent to the coordinator (chunk boxes and triangle counts)."""

    name: str
    batches: tuple[MeshBatch, ...]
    bounds: np.ndarray
    triangle_count: int
    groups: PrimitiveGroups
    chunks: SceneChunks

    @classmethod
    def from_batches(cls, name: str, batches: list[MeshBatch], face_limit: int = DEFAULT_FACE_LIMIT) -> SceneData:
        """Drop empty batches, order blended ones last, split by octree, compute bounds and groups."""
        kept = [b for b in batches if b.triangle_count > 0]
        if not kept:
            raise SceneError(f"{name}: no triangles")
        kept.sort(key=lambda b: b.alpha_mode == "BLEND")
        split, chunks = split_batches(kept, face_limit)
        boxes = np.array([b.bounds() for b in split], dtype=np.float64)
        bounds = np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
        triangles = sum(b.triangle_count for b in split)
        return cls(name, tuple(split), bounds, triangles, chunks.primitive_groups(), chunks)

    def with_face_limit(self, face_limit: int) -> SceneData:
        """The same scene split with another face limit (itself when the limit is the same)."""
        if face_limit == self.chunks.face_limit:
            return self
        return SceneData.from_batches(self.name, list(self.batches), face_limit)

    @property
    def vertex_count(self) -> int:
        return sum(b.vertex_count for b in self.batches)
