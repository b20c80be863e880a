"""The GL programs a scene's batches are drawn with: one per :class:`node.gl.shading.ShaderVariant`
its batches need, with and without fragment discards, each with its vertex array over the scene's
buffers; and the buffer of the vertex attributes only some files carry (tangents, a second uv set).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import moderngl
import numpy as np

from node.gl.shading import ShaderVariant, fragment_shader, vertex_shader
from node.scene.mesh import MeshBatch
from node.scene.packing import vertex_extras

#: Layout of :func:`node.scene.packing.vertex_extras`: tangent (xyz, w), second uv set.
EXTRAS_FORMAT = "4f 2f"
EXTRAS_ATTRIBUTES = ("in_tangent", "in_uv1")
#: Per texture slot (:data:`node.scene.material.TEXTURE_SLOTS`) one uv matrix and set.
SLOT_COUNT = 5


class ShaderPrograms:
    """The programs of ``batches`` on ``ctx``: for each variant they need (:attr:`variants`, one a
    batch), without and with discards; vertex arrays over ``content`` (the renderer's vertex buffer
    specs) and :func:`node.scene.packing.vertex_extras` when any batch has them, drawing ``index_buffer`` (uint32);
    samplers bound to ``units`` (uniform name → texture unit)."""

    def __init__(self, ctx: moderngl.Context, batches: Sequence[MeshBatch], content: list[tuple[Any, ...]],
                 index_buffer: moderngl.Buffer, units: Mapping[str, int]) -> None:
        self.variants = [ShaderVariant.of(batch) for batch in batches]
        extras = vertex_extras(batches)
        self.extras = None if extras is None else ctx.buffer(extras)
        if self.extras is not None:
            content = [*content, (self.extras, EXTRAS_FORMAT, *EXTRAS_ATTRIBUTES)]
        self.ctx, self.content = ctx, content
        self.programs: dict[tuple[ShaderVariant, bool], moderngl.Program] = {}
        for variant in sorted(set(self.variants)):
            for discards in (False, True):
                program = ctx.program(vertex_shader=vertex_shader(variant),
                                      fragment_shader=fragment_shader(variant, discards))
                for name, unit in units.items():
                    if name in program:
                        program[name].value = unit
                self.programs[variant, discards] = program
        self.vertex_arrays = self.drawing(index_buffer)
        self._other_arrays: list[dict[tuple[ShaderVariant, bool], moderngl.VertexArray]] = []

    def drawing(self, index_buffer: moderngl.Buffer) -> dict[tuple[ShaderVariant, bool], moderngl.VertexArray]:
        """A vertex array per program over the vertex buffers, drawing ``index_buffer`` (uint32)."""
        return {key: self.ctx.vertex_array(program, self.content, index_buffer=index_buffer, index_element_size=4,
                                           skip_errors=True) for key, program in self.programs.items()}

    def also_drawing(self, index_buffer: moderngl.Buffer) -> dict[tuple[ShaderVariant, bool], moderngl.VertexArray]:
        """:meth:`drawing`, released with these programs (levels of detail draw from a second index buffer)."""
        arrays = self.drawing(index_buffer)
        self._other_arrays.append(arrays)
        return arrays

    def key(self, number: int, discards: bool) -> tuple[ShaderVariant, bool]:
        """The program key of batch ``number`` drawn with or without discards."""
        return self.variants[number], discards

    def set(self, name: str, value: Any) -> None:
        """Set uniform ``name`` of every program that has it."""
        for program in self.programs.values():
            if name in program:
                program[name].value = value

    def use_uv_transforms(self, program: moderngl.Program, batch: MeshBatch) -> None:
        """Set ``program``'s per-slot uv matrices and sets from ``batch``'s material (a program of a
        variant with ``uv_transform``)."""
        material = batch.material
        transforms = [material.uv_transform(slot) for slot in range(SLOT_COUNT)]
        # mat3x2 is column-major: the (2, 3) row-major matrix transposed. The linker shortens the
        # arrays to the last slot the variant reads.
        matrices = program["u_uv_matrix"]
        matrices.write(np.array([np.reshape(t.matrix, (2, 3)).T for t in transforms[:matrices.array_length]],
                                np.float32).tobytes())
        if "u_uv_set" in program:
            sets = program["u_uv_set"]
            sets.write(np.array([t.uv_set for t in transforms[:sets.array_length]], np.int32).tobytes())

    def release(self) -> None:
        others = [array for arrays in self._other_arrays for array in arrays.values()]
        for resource in (*self.vertex_arrays.values(), *others, *self.programs.values()):
            resource.release()
        if self.extras is not None:
            self.extras.release()
