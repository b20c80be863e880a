"""A mesh batch's glTF 2.0 metallic-roughness material beyond its base colour (which
:class:`node.scene.mesh.MeshBatch` keeps with its base colour texture). No GL here.

Factors are linear; textures are (h, w, 4) uint8 with row 0 at the top of the image, sampled
with the batch's texture coordinates: metallic-roughness (B metal, G roughness), normal
(tangent space) and occlusion (R) are linear data, emissive is sRGB-encoded colour. Each texture
(:data:`TEXTURE_SLOTS`) reads the coordinate set its textureInfo names (``texCoord`` 0 or 1) through
its ``KHR_texture_transform`` (:class:`UvTransform`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: Metallic and roughness of meshes that carry no material (scans, OBJ without MTL): a matte
#: dielectric, like plaster or unglazed clay.
DEFAULT_METALLIC, DEFAULT_ROUGHNESS = 0.0, 0.6
#: A material's textures in the order the shader numbers them, with where glTF keeps each textureInfo.
TEXTURE_SLOTS = (("base_color", ("pbrMetallicRoughness", "baseColorTexture")),
                 ("metallic_roughness", ("pbrMetallicRoughness", "metallicRoughnessTexture")),
                 ("normal", ("normalTexture",)), ("occlusion", ("occlusionTexture",)),
                 ("emissive", ("emissiveTexture",)))
#: Texture coordinate sets a texture may read (TEXCOORD_0, TEXCOORD_1); a higher texCoord reads set 0.
UV_SETS = 2


@dataclass(frozen=True, slots=True)
class UvTransform:
    """How one texture reads its coordinates: set ``uv_set`` (0 or 1) mapped by ``matrix`` (2, 3)
    row-major, acting on (u, v, 1) with the renderer's uv origin at the bottom left (glTF's is at
    the top left: :meth:`of` converts)."""

    matrix: tuple[float, float, float, float, float, float] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
    uv_set: int = 0

    @classmethod
    def of(cls, offset: tuple[float, float] = (0.0, 0.0), rotation: float = 0.0,
           scale: tuple[float, float] = (1.0, 1.0), uv_set: int = 0) -> UvTransform:
        """``KHR_texture_transform``'s offset · rotation · scale in glTF uv space, rotation as
        implementations and the extension's sample model have it (the listing in its README has the
        sine's sign flipped: KhronosGroup/glTF#1563): u' = cos·u + sin·v, v' = −sin·u + cos·v."""
        c, s = np.cos(rotation), np.sin(rotation)
        gltf = np.array([[c * scale[0], s * scale[1], offset[0]], [-s * scale[0], c * scale[1], offset[1]],
                         [0.0, 0.0, 1.0]])
        flip = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 1.0], [0.0, 0.0, 1.0]])   # v ↦ 1 − v, its own inverse
        m = [float(v) for v in (flip @ gltf @ flip)[:2].reshape(-1)]
        return cls((m[0], m[1], m[2], m[3], m[4], m[5]), uv_set)

    @property
    def identity(self) -> bool:
        return self == UvTransform()


@dataclass(frozen=True, eq=False)
class SurfaceMaterial:
    """``metallic`` and ``roughness`` factors in 0…1, ``emissive`` (3,) linear radiance
    (emissiveFactor × KHR_materials_emissive_strength), ``normal_scale`` and
    ``occlusion_strength`` (the textures' glTF ``scale`` and ``strength``), the textures, each
    None when absent, and ``uv_transforms``: one :class:`UvTransform` per :data:`TEXTURE_SLOTS`
    entry (empty: all identity, set 0)."""

    metallic: float = DEFAULT_METALLIC
    roughness: float = DEFAULT_ROUGHNESS
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal_scale: float = 1.0
    occlusion_strength: float = 1.0
    metallic_roughness_texture: np.ndarray | None = None
    normal_texture: np.ndarray | None = None
    occlusion_texture: np.ndarray | None = None
    emissive_texture: np.ndarray | None = None
    uv_transforms: tuple[UvTransform, ...] = ()

    def uv_transform(self, slot: int) -> UvTransform:
        """The :class:`UvTransform` of texture slot ``slot`` (:data:`TEXTURE_SLOTS`)."""
        return self.uv_transforms[slot] if self.uv_transforms else UvTransform()

    @property
    def uv_transformed(self) -> bool:
        """Whether any texture reads other coordinates than set 0 as they are."""
        return not all(transform.identity for transform in self.uv_transforms)

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
    ``occlusion_strength`` (occlusionTexture.strength), ``emissive_strength``
    (KHR_materials_emissive_strength) and ``uv_transforms`` (each texture's texCoord and
    KHR_texture_transform, :data:`TEXTURE_SLOTS` order; empty when all are identity on set 0)."""

    normal_scale: float = 1.0
    occlusion_strength: float = 1.0
    emissive_strength: float = 1.0
    uv_transforms: tuple[UvTransform, ...] = ()


def material_extras(gltf: dict[str, Any]) -> dict[str, MaterialExtras]:
    """:class:`MaterialExtras` of a glTF JSON's named materials, by name (the loader's materials
    are matched by name); values that are not non-negative numbers are ignored."""
    extras: dict[str, MaterialExtras] = {}
    for material in gltf.get("materials", []):
        if not isinstance(material, dict) or not isinstance(material.get("name"), str):
            continue
        extension = (material.get("extensions") or {}).get("KHR_materials_emissive_strength")
        found: dict[str, Any] = {"normal_scale": _number(material.get("normalTexture"), "scale"),
                                 "occlusion_strength": _number(material.get("occlusionTexture"), "strength"),
                                 "emissive_strength": _number(extension, "emissiveStrength")}
        transforms = tuple(texture_uv_transform(_texture_info(material, path)) for _, path in TEXTURE_SLOTS)
        if not all(transform.identity for transform in transforms):
            found["uv_transforms"] = transforms
        extras[material["name"]] = MaterialExtras(**{key: value for key, value in found.items() if value is not None})
    return extras


def texture_uv_transform(info: Any) -> UvTransform:
    """The :class:`UvTransform` of a glTF textureInfo: its ``texCoord``, overridden by its
    ``KHR_texture_transform``'s, and that extension's offset, rotation and scale; values of the
    wrong type are ignored, a set beyond :data:`UV_SETS` reads set 0."""
    if not isinstance(info, dict):
        return UvTransform()
    extension = (info.get("extensions") or {}).get("KHR_texture_transform")
    extension = extension if isinstance(extension, dict) else {}
    uv_set = next((value for value in (extension.get("texCoord"), info.get("texCoord"))
                   if isinstance(value, int) and not isinstance(value, bool)), 0)
    rotation = extension.get("rotation", 0.0)
    return UvTransform.of(_pair(extension.get("offset"), (0.0, 0.0)),
                          float(rotation) if _is_number(rotation) else 0.0,
                          _pair(extension.get("scale"), (1.0, 1.0)), uv_set if 0 <= uv_set < UV_SETS else 0)


def _texture_info(material: dict[str, Any], path: tuple[str, ...]) -> Any:
    holder: Any = material
    for key in path:
        holder = holder.get(key) if isinstance(holder, dict) else None
    return holder


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bool(np.isfinite(value))


def _pair(value: Any, default: tuple[float, float]) -> tuple[float, float]:
    ok = isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)
    return (float(value[0]), float(value[1])) if ok else default


def _number(holder: Any, key: str) -> float | None:
    value = holder.get(key) if isinstance(holder, dict) else None
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value >= 0
    return float(value) if ok else None
