"""The id pass a pick draws (issue 35): only when asked, of one pixel, nothing per frame.

The pixel is drawn alone into a 1×1 framebuffer with the frame's projection narrowed to it
(:func:`tessera.tools.picking.window_matrix`), so its one sample sits at the frame pixel's centre;
only the chunks the pixel's sub-frustum keeps are drawn (the scene tree culled with the pixel's
planes and the clip's half-spaces; moved objects in their own frame), in the frame's scene state
and clip (the renderer's clip distances and discards), hidden objects left out. Each fragment
writes its batch and its triangle's number in the batch (the run's first face + ``gl_PrimitiveID``,
which counts from 0 in each draw call: one call per index run); the depth test keeps the nearest.
The answer is then computed in float64 from that triangle (:mod:`tessera.tools.picking`).
Alpha-masked cut-outs are picked as solid (the pass reads no texture).
"""

from __future__ import annotations

import moderngl
import numpy as np

from node.culling.bvh import cull
from node.culling.frustum import frustum_planes_from_matrix
from node.gl.view_tools import CLIP_FRAGMENT, CLIP_VERTEX
from node.scene.chunks import DrawRuns
from node.scene.pose import ScenePose
from tessera.geometry import Camera, Rect, view_projection
from tessera.scene.state import SceneState
from tessera.tools.picking import PickHit, cap_entry, pixel_ray, triangle_hit, window_matrix

ID_VERTEX_SHADER = """#version 330
uniform mat4 u_view_projection;
in vec3 in_position;
out vec3 v_position;
""" + CLIP_VERTEX + """
void main() {
    v_position = world_position(in_position).xyz;
    gl_Position = u_view_projection * vec4(in_position, 1.0);
}
"""

ID_FRAGMENT_SHADER = """#version 330
uniform uint u_batch;
uniform uint u_first_face;
in vec3 v_position;
out uvec4 f_id;
""" + CLIP_FRAGMENT + """
void main() {
    if (cut_away(v_position)) discard;
    f_id = uvec4(u_batch + 1u, u_first_face + uint(gl_PrimitiveID), 0u, 0u);
}
"""


class IdPass:
    """The id pass of one renderer (:class:`node.gl.renderer.TileRenderer`), made on its first pick."""

    def __init__(self, renderer) -> None:
        self.renderer = renderer
        ctx: moderngl.Context = renderer.ctx
        self.program = ctx.program(vertex_shader=ID_VERTEX_SHADER, fragment_shader=ID_FRAGMENT_SHADER)
        self.vertex_array = ctx.vertex_array(self.program, [(renderer.vertex_buffer, *renderer.vertex_format)],
                                             index_buffer=renderer.index_buffer, index_element_size=4,
                                             skip_errors=True)
        self.framebuffer = ctx.framebuffer(color_attachments=[ctx.renderbuffer((1, 1), 4, dtype="u4")],
                                           depth_attachment=ctx.depth_renderbuffer((1, 1)))
        chunks = renderer.scene.chunks
        #: Each batch's first index in the index buffer, and the triangles of its object before it.
        self.batch_first = chunks.index_bounds[chunks.batch_bounds[:-1]]
        owners = np.array([b.owner for b in renderer.scene.batches], np.int64)
        counts = np.array([b.triangle_count for b in renderer.scene.batches], np.int64)
        self.object_offset = np.array([counts[:number][owners[:number] == owners[number]].sum()
                                       for number in range(owners.size)], np.int64)

    def pick(self, camera: Camera, size: tuple[int, int], x: int, y: int,
             state: SceneState | None = None) -> PickHit | None:
        """What the centre of pixel (``x``, ``y``) of a ``size`` frame of ``camera`` sees in scene
        ``state``, cut by the renderer's tools (:meth:`TileRenderer.use_tools`); None: background."""
        renderer = self.renderer
        pose: ScenePose = renderer.pose_of(state)
        full = view_projection(camera, size, pose.bounds)
        pixel = Rect(x, y, 1, 1)
        matrix = window_matrix(pixel, size) @ full
        for name, value in renderer.view.uniforms().items():
            if name in self.program:
                self.program[name].value = value
        planes = frustum_planes_from_matrix(full, size, pixel)
        clip = renderer.culler.clip
        if clip is not None:
            planes = np.vstack((planes, clip))
        found = cull(renderer.culler.bvh, planes)
        runs = renderer.scene.chunks.runs(found.visible_first, found.visible_end)
        models = pose.models[pose.owner[list(pose.whole)]]
        moved = renderer.culler.moved.cull(planes, pose.whole, models) if pose.whole else None
        ctx = renderer.ctx
        self.framebuffer.use()
        self.framebuffer.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        renderer.view.bind()
        self._draw(runs, pose, matrix, skip=pose.skip)
        if moved is not None:
            self._draw(moved, pose, matrix)
        ids = np.frombuffer(self.framebuffer.read(components=4, dtype="u4"), np.uint32)
        if ids[0] == 0:
            return None
        return self._answer(camera, size, x, y, pose, int(ids[0]) - 1, int(ids[1]))

    def _draw(self, runs: DrawRuns, pose: ScenePose, matrix: np.ndarray, skip: np.ndarray | None = None) -> None:
        program = self.program
        model = None
        for batch, first, count in zip(runs.batch.tolist(), runs.first.tolist(), runs.count.tolist(), strict=True):
            if skip is not None and skip[batch]:
                continue
            owner = int(pose.owner[batch])
            if owner != model:
                model = owner
                program["u_view_projection"].write((matrix @ pose.models[owner]).T.astype(np.float32).tobytes())
                program["u_model"].write(pose.models[owner].T.astype(np.float32).tobytes())
            program["u_batch"].value = batch
            program["u_first_face"].value = (first - int(self.batch_first[batch])) // 3
            self.vertex_array.render(moderngl.TRIANGLES, vertices=count, first=first)

    def _answer(self, camera: Camera, size: tuple[int, int], x: int, y: int, pose: ScenePose, batch: int,
                face: int) -> PickHit | None:
        """The hit on triangle ``face`` of ``batch``."""
        renderer = self.renderer
        mesh = renderer.scene.batches[batch]
        owner = int(pose.owner[batch])
        model = pose.models[owner]
        corners = np.asarray(mesh.positions[mesh.faces[face]], dtype=np.float64) @ model[:3, :3].T + model[:3, 3]
        origin, direction = pixel_ray(camera, size, pose.bounds, x, y)
        found = triangle_hit(origin, direction, corners)
        if found is None:
            return None
        distance, normal = found
        clip = renderer.view.tools.clip
        if clip is not None and clip.cap is not None and renderer.culler.clip is not None:
            shading = np.asarray(mesh.normals[mesh.faces[face]], dtype=np.float64).sum(axis=0) @ pose.normals[owner].T
            entry = cap_entry(origin, direction, renderer.culler.clip)
            # the shader's test: the normals turn from the side of the triangle facing the eye
            if np.dot(shading, normal) < 0.0 and entry is not None and entry[0] <= distance:
                distance, row = entry   # the pixel shows the cap of the cut, on the cutting plane
                normal = -renderer.culler.clip[row, :3] / np.linalg.norm(renderer.culler.clip[row, :3])
        point = origin + distance * direction
        return PickHit(renderer.scene.objects.objects[owner].name, int(self.object_offset[batch]) + face,
                       (float(point[0]), float(point[1]), float(point[2])),
                       (float(normal[0]), float(normal[1]), float(normal[2])), float(distance))

    def release(self) -> None:
        for attachment in (*self.framebuffer.color_attachments, self.framebuffer.depth_attachment):
            attachment.release()
        for resource in (self.framebuffer, self.vertex_array, self.program):
            resource.release()
