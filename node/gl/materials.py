"""The scene's materials on the GPU (:class:`SceneMaterials`): every texture uploaded once, and a
batch's glTF metallic-roughness uniforms and maps set before it is drawn (:mod:`node.gl.shading`)."""

from __future__ import annotations

from collections.abc import Sequence

import moderngl
import numpy as np

from node.gl.shading import ShaderVariant
from node.scene.mesh import MeshBatch

GL_SRGB8_ALPHA8 = 0x8C43
#: Texture units: base colour, the peeling bounds (floor, ceiling), the material's other maps,
#: the prefiltered environment and the BRDF table.
UNIT_BASE, UNIT_FLOOR, UNIT_CEIL = 0, 1, 2
UNIT_METALLIC_ROUGHNESS, UNIT_NORMAL, UNIT_OCCLUSION, UNIT_EMISSIVE = 3, 4, 5, 6
UNIT_SPECULAR, UNIT_LUT = 7, 8
SAMPLER_UNITS = {"u_texture": UNIT_BASE, "u_floor": UNIT_FLOOR, "u_ceil": UNIT_CEIL,
                 "u_metallic_roughness": UNIT_METALLIC_ROUGHNESS, "u_normal_texture": UNIT_NORMAL,
                 "u_occlusion": UNIT_OCCLUSION, "u_emissive_texture": UNIT_EMISSIVE, "u_specular_map": UNIT_SPECULAR,
                 "u_brdf_lut": UNIT_LUT}


class SceneMaterials:
    """One mipmapped GL texture per distinct image and encoding of ``batches``, keyed by (the image
    array's id, sRGB): base colour and emissive maps are sRGB, the others linear data; a white
    texel stands in for a missing map."""

    def __init__(self, ctx: moderngl.Context, batches: Sequence[MeshBatch]) -> None:
        self.white = ctx.texture((1, 1), 4, bytes([255, 255, 255, 255]))
        self.textures: dict[tuple[int, bool], moderngl.Texture] = {}
        for batch in batches:
            for image, srgb, _ in self._maps(batch):
                if image is None or (id(image), srgb) in self.textures:
                    continue
                height, width = image.shape[:2]
                # Image row 0 is the top; GL's t = 0 is the bottom row (uvs have origin bottom-left).
                texture = ctx.texture((width, height), 4, np.ascontiguousarray(image[::-1]).tobytes(),
                                      internal_format=GL_SRGB8_ALPHA8 if srgb else None)
                texture.build_mipmaps()
                texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
                self.textures[id(image), srgb] = texture

    @staticmethod
    def _maps(batch: MeshBatch) -> tuple[tuple[np.ndarray | None, bool, int], ...]:
        """``batch``'s maps: (image (h, w, 4) uint8 or None, sRGB, texture unit)."""
        material = batch.material
        return ((batch.texture, True, UNIT_BASE),
                (material.metallic_roughness_texture, False, UNIT_METALLIC_ROUGHNESS),
                (material.normal_texture, False, UNIT_NORMAL),
                (material.occlusion_texture, False, UNIT_OCCLUSION),
                (material.emissive_texture, True, UNIT_EMISSIVE))

    def use(self, program: moderngl.Program, variant: ShaderVariant, batch: MeshBatch) -> None:
        """Set ``batch``'s material uniforms of ``program`` (of shader ``variant``) and bind its maps."""
        material = batch.material
        program["u_base_color"].value = tuple(float(v) for v in batch.base_color)
        if "u_alpha_cutoff" in program:
            program["u_alpha_cutoff"].value = batch.alpha_cutoff if batch.alpha_mode == "MASK" else -1.0
        program["u_metallic"].value = material.metallic
        program["u_roughness"].value = material.roughness
        program["u_emissive"].value = material.emissive
        if not variant.textured:
            return
        if variant.normal_map:
            program["u_normal_scale"].value = material.normal_scale
        if variant.occlusion_map:
            program["u_occlusion_strength"].value = material.occlusion_strength
        for image, srgb, unit in self._maps(batch):
            texture = self.white if image is None else self.textures.get((id(image), srgb), self.white)
            texture.use(unit)

    def release(self) -> None:
        for texture in (*self.textures.values(), self.white):
            texture.release()
        self.textures.clear()
