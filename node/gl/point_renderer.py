"""Point clouds drawn (issue 36): :class:`PointRenderer`, with the calls the GL worker makes of
:class:`node.gl.renderer.TileRenderer` — :meth:`~PointRenderer.render_tile`,
:meth:`~PointRenderer.render_frame`, :meth:`~PointRenderer.render_still` and, for sort-last,
:meth:`~PointRenderer.render_layer`.

- **What is drawn**: the frame's octree nodes within the point budget
  (:func:`tessera.points.budget.select_nodes`, once per frame, shared by every tile), those whose
  points' splats can reach the tile (their own boxes against the tile's sub-frustum pushed out by
  half the largest splat, :data:`MAX_SPLAT_PX`), by one ``glMultiDrawArraysIndirect`` whose
  commands carry each node's number as their base instance: the node's cube centre, depth and
  refinement word reach the vertex shader as instanced attributes.
- **Splats**: screen-aligned squares (``GL_POINTS``, no discard: the depth test runs early),
  sized from the spacing of the finest level drawn where the point lies (its node's depth plus the
  refinement of its octant, :func:`tessera.points.budget.refinement`), projected, at least
  ``point_size`` pixels.
- **Survey coordinates**: positions are float32 relative to the cloud's centre; the frame's
  matrix is composed in float64 with the translation to that centre and only then made float32,
  so the GL never adds two large numbers (a cloud at UTM (500000, 4000000) keeps its millimetres).
- **Eye-dome lighting** (:mod:`tessera.compositing.eye_dome`): a tile is drawn with a guard band of
  one pixel, read back with its depth, shaded and cropped: tiles equal the whole frame, bit for bit.
  Sort-last layers are read back unshaded; the coordinator shades the merged frame.
- **Upload**: the GL worker copies a cloud's first :data:`FIRST_UPLOAD_POINTS` points (its coarse
  levels: nodes are stored in hierarchy order) and holds it; the rest follows a step at a time
  between tiles (:meth:`PointRenderer.upload_step`). Until then a frame chooses among the nodes wholly
  uploaded (for those seconds a node's tiles may choose less than another's); a still's sample
  copies the rest first. A cloud whose cache entry is being checked (``checked``,
  :class:`node.scene.point_cache.PointCheck`) copies only the points that passed: nothing unchecked
  is drawn.
- The still draws every point in view up to :data:`STILL_EVERY_POINT_MAX`, beyond that every node
  in view down to the level whose points lie :data:`STILL_SPACING_PX` apart on screen (no budget,
  :func:`tessera.points.budget.still_nodes`; a render message's spacing, :meth:`PointRenderer.style`,
  0 in the coordinator's still of every point that follows); its samples are jittered
  and accumulated as the mesh renderer's are (:func:`tessera.scheduling.refinement.accumulate_still`).
  A tile given a ``stop`` is drawn in pieces of :data:`PIECE_POINTS` (the same runs in the same
  order: the same pixels) and given up between two once ``stop`` says so (:class:`DrawStopped`): a
  node drops a still's sample whose frame was cancelled (the camera moved) within a piece, not
  after every point in view.

Needs GL 4.3 (multi-draw-indirect with base instances): Mesa llvmpipe and NVIDIA have it.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any

import moderngl
import numpy as np

from node.culling.frustum import frustum_planes_from_matrix
from node.gl.context import draw_indirect, finish
from node.gl.renderer import RenderedTile, validate_rect
from node.scene.mesh import SceneError
from node.scene.pages import release_pages
from node.scene.point_cache import PointCheck
from node.scene.points import PointCloud
from tessera.balancers.projection import project_boxes
from tessera.compositing.eye_dome import guarded_rect, shade_region
from tessera.decomposition.data_partition import covering_rect
from tessera.geometry import DEFAULT_BACKGROUND, Camera, Rect, near_far_from_bounds, view_projection
from tessera.points.budget import (
    DEFAULT_POINT_SIZE,
    STILL_EVERY_POINT_MAX,
    STILL_SPACING_PX,
    pixel_scale,
    refinement,
    select_nodes,
    still_nodes,
)
from tessera.scheduling.refinement import StillPlan, Subsample, accumulate_still, jitter_matrix
from tessera.wire.messages import MAX_POINT_SIZE

#: The largest splat side in pixels (culling pushes tiles out by half of it).
MAX_SPLAT_PX = MAX_POINT_SIZE
#: Points copied to the GL at a time.
UPLOAD_POINTS = 1 << 19
#: Points a node copies to the GL before it draws (the GL worker's ``first_points``): the coarse
#: levels, 64 MB; the rest follows between tiles (:meth:`PointRenderer.upload_step`).
FIRST_UPLOAD_POINTS = 4_000_000
#: Points copied by one :meth:`PointRenderer.upload_step`: 32 MB, 20-60 ms of CPU on llvmpipe.
UPLOAD_STEP_POINTS = 1 << 21
#: Seconds a still's upload waits for the entry's check before it looks at its ``stop`` again.
CHECK_WAIT_S = 0.05
#: Points drawn between two looks at a draw's ``stop``: 20-40 ms of CPU on llvmpipe (0.2-0.35 µs a point).
PIECE_POINTS = 100_000


class DrawStopped(Exception):
    """A draw given up between two pieces: its ``stop`` said so (its frame was cancelled)."""

VERTEX_SHADER = """
#version 330
uniform mat4 u_view_projection;
uniform float u_spacing;
uniform float u_scale;
uniform float u_min_size;
uniform float u_max_size;
in vec3 in_position;
in vec4 in_color;
in vec3 in_cell;
in float in_depth;
in uint in_refine;
out vec3 v_color;
void main() {
    gl_Position = u_view_projection * vec4(in_position, 1.0);
    vec3 above = step(in_cell, in_position);
    uint octant = uint(above.x) + 2u * uint(above.y) + 4u * uint(above.z);
    float extra = float((in_refine >> (4u * octant)) & 15u);
    float side = u_spacing * exp2(-(in_depth + extra)) * u_scale / max(gl_Position.w, 1e-30);
    gl_PointSize = clamp(side, u_min_size, u_max_size);
    v_color = in_color.rgb;
}
"""
FRAGMENT_SHADER = """
#version 330
in vec3 v_color;
out vec4 f_color;
void main() {
    f_color = vec4(v_color, 1.0);
}
"""


@dataclass(frozen=True, slots=True)
class PointTile(RenderedTile):
    """A tile of a point cloud: also the ``points`` it drew and, a still's, the points in view its
    frame's choice ``left_out`` (``triangles`` is 0; chunks are octree nodes)."""

    points: int = 0
    left_out: int = 0

    def stats(self) -> dict[str, Any]:
        return {**RenderedTile.stats(self), "points": self.points, "points_left_out": self.left_out}


def draw_pieces(counts: np.ndarray) -> np.ndarray:
    """(P + 1,) int64 the first draw command of each of P pieces of about :data:`PIECE_POINTS`
    points, then the number of commands, for commands of ``counts`` (C,) points each (a command is
    never cut: a piece holds at least one)."""
    starts = np.cumsum(counts, dtype=np.int64) - counts
    piece = starts // PIECE_POINTS
    return np.concatenate([[0], np.flatnonzero(piece[1:] != piece[:-1]) + 1, [len(counts)]]).astype(np.int64)


class PointRenderer:
    """Draws tiles of ``cloud`` on ``ctx`` (the thread that owns it only) over ``background``,
    splats at least ``point_size`` pixels. ``first_points``: the points copied to the GL at once
    (None: all); the others follow by :meth:`upload_step`, and until they are there a frame chooses
    among the nodes that are (a still's sample copies them all first). Raises SceneError below GL 4.3."""

    lod = None
    #: A still draws every point in view up to this many, beyond that each place down to the level
    #: whose points lie ``still_spacing_px`` pixels apart (0: every point).
    still_every_point_max = STILL_EVERY_POINT_MAX
    still_spacing_px = STILL_SPACING_PX

    def __init__(self, ctx: moderngl.Context, cloud: PointCloud, background: Sequence[float] = DEFAULT_BACKGROUND,
                 point_size: float = DEFAULT_POINT_SIZE, first_points: int | None = None,
                 checked: PointCheck | None = None) -> None:
        if ctx.version_code < 430:
            raise SceneError(f"{cloud.name}: point clouds need GL 4.3 (multi-draw-indirect), this GL is "
                             f"{ctx.version_code}")
        self.ctx, self.scene = ctx, cloud
        self.background = background
        self.point_size = point_size
        count, nodes = cloud.point_count, cloud.nodes
        self.positions = ctx.buffer(reserve=max(count * 12, 12))
        self.colors = ctx.buffer(reserve=max(count * 4, 4))
        self.uploaded = 0
        self.checked = checked
        self._usable: np.ndarray | None = np.zeros(nodes.count, bool)
        self._upload_to(count if first_points is None else min(first_points, count))
        self.node_info = ctx.buffer(reserve=max(nodes.count * 20, 20))
        self._node_rows = np.zeros(nodes.count, [("cell", np.float32, 3), ("depth", np.float32), ("refine", np.uint32)])
        self._node_rows["cell"] = nodes.centres
        self._node_rows["depth"] = nodes.tree.depths
        self.program = ctx.program(vertex_shader=VERTEX_SHADER, fragment_shader=FRAGMENT_SHADER)
        self.vertex_array = ctx.vertex_array(self.program, [
            (self.positions, "3f", "in_position"), (self.colors, "4f1", "in_color"),
            (self.node_info, "3f 1f 1u /i", "in_cell", "in_depth", "in_refine")])
        self.commands = ctx.buffer(reserve=max(len(nodes.chunks.node) * 20, 20), dynamic=True)
        self._world_tree = cloud.world_tree
        chunks = nodes.chunks
        self._chunk_first, self._chunk_node = chunks.first, chunks.node
        self._chunk_counts = np.diff(chunks.first)
        self._chunk_boxes = chunks.boxes.astype(np.float64)
        self._framebuffer: moderngl.Framebuffer | None = None
        self._frame_key: tuple[Any, ...] | None = None
        self._chosen = np.zeros(nodes.count, bool)
        #: Points in view the last still's choice left out (0 for a moving frame's).
        self.left_out = 0

    @property
    def background(self) -> tuple[float, float, float]:
        return self._background

    @background.setter
    def background(self, value: Sequence[float]) -> None:
        rgb = tuple(float(v) for v in value)
        if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
            raise ValueError(f"background must be three numbers in 0..1, got {list(value)}")
        self._background = rgb

    @property
    def nbytes(self) -> int:
        """What the cloud is counted for: its GL buffers and its arrays held in memory."""
        return self.positions.size + self.colors.size + self.node_info.size + self.commands.size + self.scene.nbytes

    def style(self, point_size: float | None = None, spacing_px: float | None = None) -> None:
        """A frame's smallest splat side and a still's spacing on screen (px; 0: every point in view;
        None: :data:`DEFAULT_POINT_SIZE` and :data:`STILL_SPACING_PX`), as the render message says."""
        self.point_size = DEFAULT_POINT_SIZE if point_size is None else point_size
        self.still_spacing_px = STILL_SPACING_PX if spacing_px is None else spacing_px

    def use_tools(self, tools: Any) -> None:
        """Clip planes and highlights are not drawn on point clouds: a frame asking to cut one is refused."""
        if tools is not None and getattr(tools, "clip", None) is not None:
            raise ValueError("clip planes and section boxes are not drawn on point clouds")

    def pose_of(self, state: Any) -> None:
        return None

    @property
    def complete(self) -> bool:
        """Whether every point is on the GL side."""
        return self._usable is None

    def _upload_to(self, end: int) -> None:
        """Copy points up to ``end`` to the GL (the mapped pages handed back), the nodes whose
        points all arrived made usable; with a ``checked`` entry, only those that passed their
        check (SceneError when none more can: it failed)."""
        cloud = self.scene
        check = self.checked
        if check is not None and end > check.points:
            if check.failed is not None and check.points <= self.uploaded:
                raise SceneError(f"{cloud.name}: {check.failed}")
            end = check.points
        for first in range(self.uploaded, end, UPLOAD_POINTS):
            last = min(first + UPLOAD_POINTS, end)
            self.positions.write(np.ascontiguousarray(cloud.positions[first:last], np.float32), offset=first * 12)
            self.colors.write(np.ascontiguousarray(cloud.colors[first:last], np.uint8), offset=first * 4)
            release_pages(cloud.positions, first, last)
            release_pages(cloud.colors, first, last)
        self.uploaded = max(self.uploaded, end)
        if self.uploaded >= cloud.point_count:
            self._usable = None
        else:
            self._usable = cloud.nodes.first[1:] <= self.uploaded

    def upload_step(self, points: int | None = None) -> bool:
        """Copy the next ``points`` points (None: :data:`UPLOAD_STEP_POINTS`) to the GL (nodes are in
        hierarchy order: the coarse levels went first); whether every point is there now."""
        step = UPLOAD_STEP_POINTS if points is None else points
        self._upload_to(min(self.uploaded + step, self.scene.point_count))
        return self.complete

    def upload_all(self, stop: Callable[[], bool] | None = None) -> None:
        """Copy the points not on the GL side yet, a step at a time (waiting for their check);
        DrawStopped once ``stop()`` is true between two steps."""
        while not self.upload_step():
            if stop is not None and stop():
                raise DrawStopped(f"stopped uploading at point {self.uploaded} of {self.scene.point_count}")
            if self.checked is not None:
                self.checked.wait(self.uploaded + 1, CHECK_WAIT_S)

    def choose(self, camera: Camera, size: tuple[int, int], budget: int | None,
               stop: Callable[[], bool] | None = None) -> np.ndarray:
        """(M,) bool the frame's nodes within ``budget`` (None: a still's, every node in view down to
        :attr:`still_spacing_px`, :func:`tessera.points.budget.still_nodes`, every point uploaded
        first, :meth:`upload_all` with ``stop``) among the nodes on the GL side, their refinement
        written to the node buffer, a still's points in view left out in :attr:`left_out`; the last
        frame's kept for its other tiles while no more nodes arrived."""
        if budget is None and not self.complete:
            self.upload_all(stop)
        usable = self._usable
        key = (camera, size, budget, self.still_spacing_px, self.still_every_point_max,
               None if usable is None else self.uploaded)
        if key != self._frame_key:
            tree = self._world_tree
            if budget is None:
                self._chosen = still_nodes(tree, camera, size, self.scene.bounds, self.scene.nodes.spacing,
                                           usable, self.still_spacing_px, self.still_every_point_max)
                seen = select_nodes(tree, camera, size, self.scene.bounds, None, usable)
                self.left_out = int(tree.counts[seen & ~self._chosen].sum())
            else:
                self._chosen = select_nodes(tree, camera, size, self.scene.bounds, budget, usable)
                self.left_out = 0
            self._node_rows["refine"] = refinement(self._world_tree, self._chosen)
            self.node_info.write(self._node_rows.tobytes())
            self._frame_key = key
        return self._chosen

    def _matrix(self, camera: Camera, size: tuple[int, int], subsample: Subsample | None) -> np.ndarray:
        """(4, 4) float64 the frame's matrix from positions relative to the cloud's centre."""
        translate = np.identity(4)
        translate[:3, 3] = self.scene.centre
        offset = None if subsample is None else subsample.offset
        return jitter_matrix(offset, size) @ view_projection(camera, size, self.scene.bounds) @ translate

    def _draw(self, camera: Camera, size: tuple[int, int], drawn: Rect, chosen: np.ndarray,
              subsample: Subsample | None, stop: Callable[[], bool] | None = None
              ) -> tuple[np.ndarray, np.ndarray, int]:
        """Draw the runs of the ``chosen`` nodes that touch ``drawn`` (:class:`node.scene.points.PointChunks`,
        in their order) into the frame-sized framebuffer scissored to it; (colour (h, w, 3) uint8,
        window depth (h, w) float32, points drawn). With ``stop``: in pieces (:func:`draw_pieces`),
        DrawStopped once ``stop()`` is true between two."""
        matrix = self._matrix(camera, size, subsample)
        planes = frustum_planes_from_matrix(matrix, size, drawn, MAX_SPLAT_PX / 2.0 + 1.0)
        ids = np.flatnonzero(chosen[self._chunk_node])
        boxes = self._chunk_boxes[ids]
        corner = np.where(planes[None, :, :3] >= 0.0, boxes[:, None, 1, :], boxes[:, None, 0, :])
        touching = ((corner * planes[None, :, :3]).sum(axis=-1) + planes[None, :, 3] >= 0.0).all(axis=1)
        ids = ids[touching]
        width, height = size
        framebuffer = self._framebuffer_for(size)
        gl_box = (drawn.x, height - drawn.y1, drawn.w, drawn.h)
        framebuffer.viewport = (0, 0, width, height)
        framebuffer.scissor = gl_box
        framebuffer.use()
        framebuffer.clear(*self._background, 1.0, depth=1.0, viewport=gl_box)
        points = int(self._chunk_counts[ids].sum())
        if ids.size:
            # moderngl draws arrays indirect with the elements' command stride (5 words): one spare.
            commands = np.stack([self._chunk_counts[ids], np.ones(ids.size, np.int64), self._chunk_first[ids],
                                 self._chunk_node[ids], np.zeros(ids.size, np.int64)], axis=1).astype(np.uint32)
            self.commands.write(commands.tobytes())
            self.program["u_view_projection"].write(matrix.T.astype(np.float32).tobytes())
            self.program["u_spacing"].value = self.scene.nodes.spacing
            self.program["u_scale"].value = pixel_scale(camera, size)
            self.program["u_min_size"].value = self.point_size
            self.program["u_max_size"].value = MAX_SPLAT_PX
            ctx = self.ctx
            ctx.enable(moderngl.DEPTH_TEST | moderngl.PROGRAM_POINT_SIZE)
            ctx.disable(moderngl.BLEND | moderngl.CULL_FACE)
            pieces = draw_pieces(self._chunk_counts[ids]) if stop is not None else np.array([0, ids.size])
            for first, end in itertools.pairwise(pieces):
                if first and stop is not None and stop():
                    raise DrawStopped(f"stopped after {first} of {ids.size} runs")
                draw_indirect(self.vertex_array, self.commands, moderngl.POINTS, int(end - first), int(first))
        finish(self.ctx)
        color = framebuffer.read(viewport=gl_box, components=3, alignment=1)
        depth = framebuffer.read(viewport=gl_box, components=1, attachment=-1, alignment=1, dtype="f4")
        return (np.frombuffer(color, np.uint8).reshape(drawn.h, drawn.w, 3)[::-1],
                np.frombuffer(depth, np.float32).reshape(drawn.h, drawn.w)[::-1], points)

    def render_tile(self, camera: Camera, size: tuple[int, int], rect: Rect, slot: Hashable | None = None,
                    state: Any = None, subsample: Subsample | None = None, lod_error_px: float = 0.0,
                    point_budget: int | None = None, stop: Callable[[], bool] | None = None) -> PointTile:
        """The ``rect`` part of the ``size`` frame seen by ``camera``: the nodes within
        ``point_budget`` points (None: every point in view), shaded by EDL; as ``subsample`` of a
        still (None: a plain frame); given up (DrawStopped) between two pieces once ``stop()`` is
        true (None: drawn at once). ``slot``, ``state`` and ``lod_error_px`` are the mesh
        renderer's and change nothing here."""
        validate_rect(rect, size)
        started = time.perf_counter()
        chosen = self.choose(camera, size, point_budget, stop)
        drawn = guarded_rect(rect, size)
        color, depth, points = self._draw(camera, size, drawn, chosen, subsample, stop)
        rendered = time.perf_counter()
        near, far = near_far_from_bounds(camera, self.scene.bounds)
        pixels = shade_region(color, depth, drawn, rect, near, far)
        done = time.perf_counter()
        return PointTile(rect, pixels, (rendered - started) * 1e3 + (done - rendered) * 1e3, 0.0, 0,
                            int(chosen.sum()), int((~chosen).sum()), 0.0, "points", points=points,
                            left_out=self.left_out)

    def render_layer(self, camera: Camera, size: tuple[int, int], point_budget: int | None = None,
                     subsample: Subsample | None = None, stop: Callable[[], bool] | None = None
                     ) -> PointTile | None:
        """A sort-last layer: the frame's nodes within ``point_budget`` (chosen from the whole tree)
        that this share holds, unshaded, with depth, over the rect they can cover; None when none
        is on screen; ``stop`` as :meth:`render_tile`'s."""
        started = time.perf_counter()
        chosen = self.choose(camera, size, point_budget, stop)
        ids = np.flatnonzero(chosen[self._chunk_node])
        boxes = self._chunk_boxes[ids] + self.scene.centre
        bounds = project_boxes(boxes.reshape(-1, 6), camera, size, self.scene.bounds)
        grow = MAX_SPLAT_PX / 2.0 + 1.0
        bounds[:, :2] -= grow
        bounds[:, 2:] += grow
        rect = covering_rect(bounds, size)
        if rect is None:
            return None
        color, depth, points = self._draw(camera, size, rect, chosen, subsample, stop)
        return PointTile(rect, np.ascontiguousarray(color), (time.perf_counter() - started) * 1e3, 0.0, 0,
                            int(chosen.sum()), int((~chosen).sum()), 0.0, "points",
                            np.ascontiguousarray(depth), points=points, left_out=self.left_out)

    def render_frame(self, camera: Camera, size: tuple[int, int], state: Any = None,
                     subsample: Subsample | None = None, lod_error_px: float = 0.0,
                     point_budget: int | None = None) -> PointTile:
        """The whole ``size`` frame (:meth:`render_tile`)."""
        return self.render_tile(camera, size, Rect(0, 0, *size), subsample=subsample, point_budget=point_budget)

    def render_still(self, camera: Camera, size: tuple[int, int], samples: StillPlan | int,
                     state: Any = None) -> np.ndarray:
        """The progressive still: every point, samples accumulated as the coordinator does."""
        plan = samples if isinstance(samples, StillPlan) else StillPlan(samples)
        return accumulate_still(lambda subsample: self.render_frame(camera, size, subsample=subsample).pixels,
                                size, plan).mean()

    def _framebuffer_for(self, size: tuple[int, int]) -> moderngl.Framebuffer:
        framebuffer = self._framebuffer
        if framebuffer is None or framebuffer.size != size:
            self._release_framebuffer()
            framebuffer = self.ctx.framebuffer(color_attachments=[self.ctx.renderbuffer(size, 4)],
                                               depth_attachment=self.ctx.depth_renderbuffer(size))
            self._framebuffer = framebuffer
        return framebuffer

    def _release_framebuffer(self) -> None:
        if self._framebuffer is not None:
            for attachment in (*self._framebuffer.color_attachments, self._framebuffer.depth_attachment):
                attachment.release()
            self._framebuffer.release()
            self._framebuffer = None

    def release(self) -> None:
        """Free the GL objects (the context stays the caller's)."""
        self._release_framebuffer()
        for resource in (self.vertex_array, self.program, self.commands, self.node_info, self.colors, self.positions):
            resource.release()

