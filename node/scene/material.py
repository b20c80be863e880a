"""A mesh batch's glTF 2.0 metallic-roughness material beyond its base colour (which
:class:`node.scene.mesh.MeshBatch` keeps with its base colour texture). No GL here.

Factors are linear; textures are (h, w, 4) uint8 with row 0 at the top of the image, sampled
with the batch's texture coordinates: metallic-roughness (B metal, G roughness), normal
(tangent space) and occlusion (R) are linear data, emissive is sRGB-encoded colour.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Metallic and roughness of meshes that carry no material (scans, OBJ without MTL): a matte
#: dielectric, like plaster or unglazed clay.
DEFAULT_METALLIC, DEFAULT_ROUGHNESS = 0.0, 0.6


@dataclass(frozen=True, eq=False)
class SurfaceMaterial:
    """``metallic`` and ``roughness`` factors in 0…1, ``emissive`` (3,) linear radiance
    (emissiveFactor × KHR_materials_emissive_strength), ``normal_scale`` and
    ``occlusion_strength`` (the textures' glTF ``scale`` and ``strength``) and the textures, each
    None when absent."""

    metallic: float = DEFAULT_METALLIC
    roughness: float = DEFAULT_ROUGHNESS
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal_scale: float = 1.0
    occlusion_strength: float = 1.0
    metallic_roughness_texture: np.ndarray | None = None
    normal_texture: np.ndarray | None = None
    occlusion_texture: np.ndarray | None = None
    emissive_texture: np.ndarray | None = None

    def textures(self) -> tuple[np.ndarray | None, ...]:
        """Metallic-roughness, normal, occlusion and emissive textures, in that order."""
        return (self.metallic_roughness_texture, self.normal_texture, self.occlusion_texture,
                self.emissive_texture)

    @property
    def textured(self) -> bool:
        """Whether any of its textures is present (the batch then needs texture coordinates)."""
        return any(texture is not None for texture in self.textures())


def emissive_strengths(gltf: dict[str, Any]) -> dict[str, float]:
    """``KHR_materials_emissive_strength`` of a glTF JSON's materials, by material name (the
    loader's materials are matched by name: trimesh drops the extension)."""
    strengths: dict[str, float] = {}
    for material in gltf.get("materials", []):
        if not isinstance(material, dict):
            continue
        extension = (material.get("extensions") or {}).get("KHR_materials_emissive_strength")
        strength = extension.get("emissiveStrength") if isinstance(extension, dict) else None
        if isinstance(material.get("name"), str) and isinstance(strength, (int, float)) and strength >= 0:
            strengths[material["name"]] = float(strength)
    return strengths
