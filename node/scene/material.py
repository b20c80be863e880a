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


@dataclass(frozen=True, slots=True)
class MaterialExtras:
    """What trimesh drops of a glTF material: ``normal_scale`` (normalTexture.scale),
    ``occlusion_strength`` (occlusionTexture.strength) and ``emissive_strength``
    (KHR_materials_emissive_strength)."""

    normal_scale: float = 1.0
    occlusion_strength: float = 1.0
    emissive_strength: float = 1.0


def material_extras(gltf: dict[str, Any]) -> dict[str, MaterialExtras]:
    """:class:`MaterialExtras` of a glTF JSON's named materials, by name (the loader's materials
    are matched by name); values that are not non-negative numbers are ignored."""
    extras: dict[str, MaterialExtras] = {}
    for material in gltf.get("materials", []):
        if not isinstance(material, dict) or not isinstance(material.get("name"), str):
            continue
        extension = (material.get("extensions") or {}).get("KHR_materials_emissive_strength")
        found = {"normal_scale": _number(material.get("normalTexture"), "scale"),
                 "occlusion_strength": _number(material.get("occlusionTexture"), "strength"),
                 "emissive_strength": _number(extension, "emissiveStrength")}
        extras[material["name"]] = MaterialExtras(**{key: value for key, value in found.items() if value is not None})
    return extras


def _number(holder: Any, key: str) -> float | None:
    value = holder.get(key) if isinstance(holder, dict) else None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0
    return float(value) if ok else None
