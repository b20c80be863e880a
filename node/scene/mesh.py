"""One drawable mesh in world space (:class:`MeshBatch`) and the error every scene loader raises.
No GL here."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from node.scene.material import SurfaceMaterial

#: Linear base colour of meshes that carry no material (scans): a warm light grey.
DEFAULT_BASE_COLOR = (0.60, 0.57, 0.52, 1.0)


class SceneError(ValueError):
    """A scene that cannot be loaded; the message is one line naming the file and the reason."""


@dataclass(frozen=True, eq=False)
class MeshBatch:
    """One drawable mesh in world space (one material, one draw call over an index range).

    ``positions`` (N, 3) float32, ``normals`` (N, 3) float32 unit length (float16 when mapped from a
    scene cache; None: smooth normals are computed when the scene is split, after the vertices have
    their final order), ``faces`` (F, 3) uint32,
    ``uvs`` (N, 2) float32 with origin bottom-left (GL convention) or None, ``colors`` (N, 4)
    float32 linear 0…1 or None, ``base_color`` (4,) float32 linear, ``texture`` (h, w, 4) uint8
    sRGB with row 0 at the top of the image or None. ``alpha_mode`` is glTF's OPAQUE, MASK or BLEND.
    ``material``: metallic, roughness, emission and the other maps (:mod:`node.scene.material`).
    ``owner``: the index of the scene object it belongs to (:class:`tessera.scene.graph.ObjectGraph`),
    whose model matrix moves it. ``tangents`` (N, 4) float32: a glTF file's TANGENTs in world space
    (unit xyz, w = ±1 the bitangent's sign) or None; ``uvs1`` (N, 2) float32: its TEXCOORD_1 (origin
    bottom-left) or None.
    """

    name: str
    positions: np.ndarray
    normals: np.ndarray | None
    faces: np.ndarray
    uvs: np.ndarray | None = None
    colors: np.ndarray | None = None
    base_color: np.ndarray = field(default_factory=lambda: np.asarray(DEFAULT_BASE_COLOR, np.float32))
    texture: np.ndarray | None = None
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    owner: int = 0
    material: SurfaceMaterial = field(default_factory=SurfaceMaterial)
    tangents: np.ndarray | None = None
    uvs1: np.ndarray | None = None

    @property
    def triangle_count(self) -> int:
        return len(self.faces)

    @property
    def vertex_count(self) -> int:
        return len(self.positions)

    def with_vertices(self, order: np.ndarray, faces: np.ndarray, positions: np.ndarray | None = None) -> MeshBatch:
        """This batch with vertices ``order`` (M,) (indices of its vertices: every per-vertex array
        taken in that order) and ``faces`` (F', 3) indexing them; ``positions``: the positions in that
        order when already at hand."""
        def take(values: np.ndarray | None) -> np.ndarray | None:
            return None if values is None else values[order]

        moved = self.positions[order] if positions is None else positions
        return dataclasses.replace(self, positions=moved, normals=take(self.normals),
                                   uvs=take(self.uvs), colors=take(self.colors), tangents=take(self.tangents),
                                   uvs1=take(self.uvs1), faces=np.asarray(faces, np.uint32))

    def bounds(self) -> np.ndarray:
        """World-space AABB (2, 3) float64 of the vertices the faces use."""
        used = np.zeros(len(self.positions), dtype=bool)
        used[self.faces.reshape(-1)] = True
        points = self.positions[used]
        return np.stack([points.min(axis=0), points.max(axis=0)]).astype(np.float64)
