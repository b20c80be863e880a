"""Retained-mode tile renderer (seed 002): the scene is uploaded once, then any screen tile of any
camera is drawn and read back.

A tile is drawn with the full frame's camera, projection and viewport into a frame-sized
framebuffer, with the scissor box set to the tile (seeds 001/002: tiles join without seams).
Rasterisation, attribute interpolation and texture LOD (which uses 2×2 pixel quads) are then the
very same as in a full render, so a tile is bit-identical to that region of the full frame — a
tile-sized framebuffer with a shifted viewport moves the quad grid and the interpolation origin by
the tile offset and changes low bits. One framebuffer
serves every tile of a frame size however the balancer reshapes the tiles.

Geometry lives in one interleaved vertex buffer and one index buffer (batches in order, each
batch's faces in chunk order, :mod:`node.scene.chunks`). Each tile is culled first
(:class:`node.culling.tiles.TileCuller`: off, CPU, GPU or hybrid, seed 001) against the tile's
sub-frustum of the same full-frame matrix the tile is drawn with; then each batch with something in
the tile gets its material uniforms once and draws its kept index ranges. Culled chunks lie wholly
outside the (padded) tile frustum, so they would not have written a pixel of the tile: culling
never changes the image.

Both culling paths hand over a buffer of indirect draw commands (the CPU writes one per run of
touching visible chunks, the GPU one per chunk, zero-count where culled), and each batch is drawn
with one ``render_indirect`` (glMultiDrawElementsIndirect) over its slice: see
:mod:`node.culling.tiles` for why it is kept over one ``render(first=, vertices=)`` per run.
Below GL 4.3 (no multi-draw-indirect, no GPU culling) the runs are drawn one call each.

Depth layers (:meth:`TileRenderer.render_layer`, for the hybrid and sort-last modes of
:mod:`tessera.compositing.depth_merge`): the same draw of a rect — the same full-frame viewport, scissor
and near/far — with a given list of chunks instead of the rect's culled ones, and the rect's depth
read back too, as float32 window depth from the one depth buffer format every node uses (moderngl's
24-bit depth renderbuffer, cleared to 1.0 = far, ``GL_LESS``). Equal surfaces drawn on different
nodes therefore carry equal depth bits. Blended chunks may be drawn apart, over such a layer
(:meth:`TileRenderer.render_blend`, sort-last): their fragments in front of the layer are peeled
by depth (the fragment shader keeps those strictly between two per-pixel depth textures), and for
each m the m nearest are accumulated in draw order, premultiplied, into a cleared buffer: a
:class:`tessera.compositing.layers.BlendLayer` the compositor lays over the merged frame.

Objects: a tile is drawn in a scene state (:class:`node.scene.pose.ScenePose`): each
batch with its object's model matrix (folded into the view-projection uniform, so an unmoved
object draws exactly as before) and normal matrix; a moved object is culled per tile in its own
frame (:mod:`node.culling.objects`; drawn whole among listed chunks), a hidden one not drawn at
all; near/far come from the state's bounds. Tile and whole frame get the same uniforms.
Shading: the glTF metallic-roughness BRDF with image-based light and a camera-attached key light,
tone mapped (:mod:`node.gl.shading`, one shader for every draw).

Anti-aliasing (``--msaa N``): plain tiles and whole frames are drawn into a frame-sized
multisampled framebuffer, scissored to the tile, and resolved (a blit, which the scissor box
limits to the tile) into the single-sample one they are read from. A pixel's samples never leave
it, so a tile is still that region of the whole frame, bit for bit. Depth layers stay at one
sample: merging layers picks one surface per pixel by its depth, which a resolved edge pixel
(a mix of surfaces) does not have; so hybrid and sort-last frames are 1x frames. On a software
rasterizer (llvmpipe, where multisampling costs several one-sample frames: see the design notes)
``--msaa auto`` draws a grid of samples a pixel instead, chosen by frame size
(:class:`node.gl.shading.AntialiasingChoice`): the same projection over a viewport kx × ky times as
large, so block (i, j) is pixel (i, j)'s samples (the pair, 2 × 1, ¼ pixel left and right of its
centre, one draw); these frames (and ``--msaa filter``'s one sample) are resolved by
:func:`tessera.antialiasing.resolve_grid` (the filtered ones by a compiled pass once loaded,
:mod:`node.gl.resolve`), the filtered ones drawn with a guard band of one pixel
(clipped to the frame) so that the filtered tile is still that region of the filtered whole frame,
and with their texture LOD bias.

The progressive still: a render may be a still's ``subsample``
(:class:`tessera.scheduling.refinement.Subsample`): the whole frame shifted by a sub-pixel offset, a
translation applied after the projection (:func:`tessera.scheduling.refinement.jitter_matrix`) —
tiles, layers and whole frames alike, culling with the same matrix — and textures read with its
LOD bias; :meth:`TileRenderer.render_still` accumulates a still's samples as the coordinator does.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from typing import Any

import moderngl
import numpy as np

from node.culling.lod import LodCut
from node.culling.switch import CullMode, SwitchParams
from node.culling.tiles import TileCull, TileCuller
from node.gl.buffers import upload_geometry
from node.gl.context import draw_indirect, finish
from node.gl.id_pass import IdPass
from node.gl.image_lighting import prefiltered_environment
from node.gl.lod_draws import LodDraws
from node.gl.materials import SAMPLER_UNITS, UNIT_CEIL, UNIT_FLOOR, UNIT_LUT, UNIT_SPECULAR, SceneMaterials
from node.gl.programs import ShaderPrograms
from node.gl.resolve import resolve
from node.gl.shading import ShaderVariant, ShadingOptions, resolve_antialiasing
from node.gl.shared import SharedGL
from node.gl.view_tools import ViewTools, ViewToolsGL
from node.scene.chunks import DrawRuns
from node.scene.data import SceneData
from node.scene.lod import LodTree
from node.scene.packing import PackedGeometry, pack
from node.scene.pose import ScenePose
from tessera.antialiasing import FILTERED_LOD_BIAS, guarded
from tessera.geometry import DEFAULT_BACKGROUND, Camera, Rect, look_at, view_projection
from tessera.scene.state import SceneState
from tessera.scheduling.refinement import StillPlan, Subsample, accumulate_still, grid_subsample, jitter_matrix
from tessera.tools.picking import PickHit, window_matrix

#: Key light direction in view space (towards the light): from the eye, a little above and right,
#: so that surfaces facing the viewer still show their relief.
HEADLIGHT_VIEW = (0.25, 0.4, 1.0)


#: What :meth:`TileRenderer._draw` draws of a batch, in this order: its culled chunks' commands,
#: the whole batch (a moved object's), its coarse levels of detail.
CULLED, WHOLE, COARSE = 0, 1, 2
#: Most blended fragments per pixel :meth:`TileRenderer.render_blend` peels apart (beyond them the
#: compositor takes all of a pixel's fragments in front of the node's own layer together).
MAX_BLEND_LAYERS = 4
#: How :meth:`TileRenderer._use_material` blends blended batches: over the frame (as shown), or
#: premultiplied into a cleared buffer, alpha accumulated as coverage (:meth:`TileRenderer.render_blend`).
BLEND_OVER = (moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA)
BLEND_ACCUMULATE = (moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA, moderngl.ONE, moderngl.ONE_MINUS_SRC_ALPHA)


@dataclass(frozen=True, slots=True)
class BlendedFragments:
    """Blended chunks drawn over a depth layer (:meth:`TileRenderer.render_blend`), K layers:
    ``depth`` (K, h, w) float32 the m-th nearest fragment's (1.0 where there are fewer), ``color``
    (K, h, w, 3) uint8 the m nearest accumulated premultiplied in draw order, ``alpha`` (K, h, w)
    uint8 their coverage; ``triangles`` drawn, times in ms."""

    color: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    triangles: int
    render_ms: float
    readback_ms: float


@dataclass(frozen=True, slots=True)
class RenderedTile:
    """A tile's pixels (rect.h, rect.w, 3) uint8, row 0 at the top, its measured phases (ms,
    ``render_ms`` includes culling), and what culling did: ``triangles`` submitted, chunks drawn
    and culled (of the scene's chunks), ``cull_ms``, ``cull_path`` "off", "cpu", "gpu" or "list";
    ``depth`` (rect.h, rect.w) float32 window depth, 1.0 where nothing was drawn, for a depth layer
    (None for a plain tile)."""

    rect: Rect
    pixels: np.ndarray
    render_ms: float
    readback_ms: float
    triangles: int
    chunks_drawn: int
    chunks_culled: int
    cull_ms: float
    cull_path: str
    depth: np.ndarray | None = None

    def stats(self) -> dict[str, Any]:
        """The per-tile counters a node reports in ``tile_sent.stats``."""
        return {"triangles": self.triangles, "chunks_drawn": self.chunks_drawn, "chunks_culled": self.chunks_culled,
                "cull_ms": round(self.cull_ms, 4), "cull_path": self.cull_path}


def headlight_direction(camera: Camera) -> tuple[float, float, float]:
    """World-space unit vector towards the camera-attached light (:data:`HEADLIGHT_VIEW`)."""
    rotation = look_at(camera.eye, camera.target, camera.up)[:3, :3]
    direction = rotation.T @ np.asarray(HEADLIGHT_VIEW, dtype=np.float64)
    return tuple(float(v) for v in direction / np.linalg.norm(direction))


def validate_rect(rect: Rect, size: tuple[int, int]) -> None:
    """Raise ValueError unless ``rect`` is non-empty and inside a ``size`` = (w, h) frame."""
    width, height = size
    if width <= 0 or height <= 0:
        raise ValueError(f"frame size must be positive, got {width}x{height}")
    if rect.w <= 0 or rect.h <= 0 or rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
        raise ValueError(f"tile {rect.as_list()} is empty or outside the {width}x{height} frame")


def windowed(size: tuple[int, int], rect: Rect, window: Rect | None) -> tuple[tuple[int, int], Rect]:
    """The framebuffer size and the rect in it of ``rect`` of the ``size`` frame drawn in ``window``
    (a poster's part, :mod:`tessera.scheduling.render_jobs`; None: the whole frame, as they are);
    ValueError for a rect or window outside what holds it."""
    validate_rect(rect, size)
    if window is None:
        return size, rect
    validate_rect(window, size)
    inside = Rect(rect.x - window.x, rect.y - window.y, rect.w, rect.h)
    validate_rect(inside, (window.w, window.h))
    return (window.w, window.h), inside


def cull_back_faces(ctx: moderngl.Context, cull: bool, culling: bool) -> bool:
    """Turn ``ctx``'s culling of back faces to ``cull`` when it is not (``culling``: whether it is); ``cull``."""
    if cull != culling:
        (ctx.enable if cull else ctx.disable)(moderngl.CULL_FACE)
    return cull


class TileRenderer:
    """Draws tiles of ``scene`` on ``ctx`` with ``culling`` (hybrid switch ``switch_params``) and
    ``shading``; use it only on the thread that owns ``ctx``. ``packed``: the scene's batches as
    :func:`node.scene.packing.pack` packs them, when already done or mapped from a scene cache
    (None: packed here). :attr:`antialiasing`: how plain tiles and whole frames of each size are
    drawn (as :func:`node.gl.shading.resolve_antialiasing` resolves ``--msaa``). ``shared``: the
    framebuffers and lighting of the renderers on ``ctx`` (None: its own, released with it). Raises
    CullingUnavailableError for gpu culling without GL 4.3, EnvironmentError for an unreadable
    environment file."""

    def __init__(self, ctx: moderngl.Context, scene: SceneData,
                 background: Sequence[float] = DEFAULT_BACKGROUND, culling: CullMode = CullMode.AUTO,
                 switch_params: SwitchParams = SwitchParams(),
                 packed: PackedGeometry | None = None,
                 shading: ShadingOptions = ShadingOptions(), shared: SharedGL | None = None) -> None:
        self.ctx = ctx
        self.scene = scene
        self.background = background
        self.shading = shading
        #: What frames of each size are drawn with (``--msaa``: :func:`resolve_antialiasing`).
        self.antialiasing = resolve_antialiasing(shading.msaa, ctx.info["GL_RENDERER"], ctx.max_samples)
        # First: they raise before any GL object of the scene exists to leak.
        prefiltered_environment(shading.environment)
        self.culler = TileCuller(ctx, scene.chunks, culling, switch_params)
        self._owns_shared = shared is None
        self.shared = SharedGL(ctx) if shared is None else shared
        self.lighting = self.shared.lighting(shading.environment)
        packed = pack(scene.batches) if packed is None else packed
        self.vertex_bounds = packed.vertex_bounds
        chunks = scene.chunks
        self.vertex_buffer, self.index_buffer = upload_geometry(ctx, packed,
                                                                chunks.index_bounds[chunks.batch_bounds])
        #: The programs of the batches' shader variants, without and with discards (:meth:`_program_key`).
        self.shaders = ShaderPrograms(
            ctx, scene.batches, [(self.vertex_buffer, packed.layout.gl_format, *packed.layout.attributes)],
            self.index_buffer, SAMPLER_UNITS)
        #: The vertex buffer's format and attribute names (the id pass draws from it too).
        self.vertex_format = (packed.layout.gl_format, *packed.layout.attributes)
        self.materials = SceneMaterials(ctx, scene.batches)
        #: The frame's clip planes, section box and highlight (:meth:`use_tools`).
        self.view = ViewToolsGL(ctx, scene)
        self._set_uniforms(self.view.uniforms())
        self._id_pass: IdPass | None = None
        #: Draw by glMultiDrawElementsIndirect (GL 4.3); otherwise one draw call per index run.
        self.multi_draw = ctx.version_code >= 430
        self.framebuffers = self.shared.framebuffers
        self._blending = False
        #: Whether blended fragments are being peeled (:meth:`render_blend`: drawn with discards).
        self._peeling = False
        #: How blended batches are drawn (None: into depth only, as if opaque, colour writes off).
        self._blend_func: tuple[int, ...] | None = BLEND_OVER
        self._base_pose = ScenePose.of(scene, None)
        self._pose: tuple[SceneState | None, ScenePose] = (None, self._base_pose)
        #: The scene's levels of detail once attached (:meth:`attach_lod`).
        self.lod: LodDraws | None = None

    def attach_lod(self, tree: LodTree) -> None:
        """Upload ``tree``'s levels: from now on plain tiles and sort-last layers asked for an error
        bound draw its coarse nodes where they are within it."""
        if self.lod is not None:
            self.lod.release()
        self.lod = LodDraws(tree, self.vertex_bounds, self.shaders, self.scene)

    def level_cut(self, camera: Camera, size: tuple[int, int], error_px: float) -> LodCut:
        """The frame's levels (:meth:`LodDraws.cut`) for ``camera`` in a ``size`` frame within
        ``error_px`` pixels; full detail without levels, without a bound, or with a culling mode
        that cannot leave chunks out."""
        if self.lod is None or error_px <= 0.0 or not self.culler.takes_levels:
            return LodCut.full()
        return self.lod.cut(camera, size, error_px)

    @property
    def background(self) -> tuple[float, float, float]:
        return self._background

    @background.setter
    def background(self, value: Sequence[float]) -> None:
        rgb = tuple(float(v) for v in value)
        if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
            raise ValueError(f"background must be three numbers in 0..1, got {list(value)}")
        self._background = rgb

    def render_tile(self, camera: Camera, size: tuple[int, int], rect: Rect,
                    slot: Hashable | None = None, state: SceneState | None = None,
                    subsample: Subsample | None = None, lod_error_px: float = 0.0,
                    window: Rect | None = None) -> RenderedTile:
        """Draw the ``rect`` part of the ``size`` = (w, h) frame seen by ``camera`` in scene ``state``
        (None: the base pose), as ``subsample`` of a progressive still (None: a plain frame, drawn
        and resolved as :attr:`antialiasing` says for the size: a filtered one drawn, culled and read
        with its guard band); a plain frame at the levels of detail within ``lod_error_px`` pixels
        (0: full detail; a still's samples always are). ``slot`` names the tile for the hybrid
        culling switch (default: the rect itself). ``window``: the part of the frame (a poster's,
        :mod:`tessera.scheduling.render_jobs`) drawn into a framebuffer of its own size, the
        projection narrowed to it (None: the whole frame's); the frame's size decides the samples."""
        started = time.perf_counter()
        slot = tuple(rect.as_list()) if slot is None else slot
        frame, whole = size, rect
        size, rect = windowed(size, rect, window)
        antialiasing = self.antialiasing.for_size(frame)
        kx, ky = antialiasing.grid
        if subsample is None:   # a filtered frame reads textures one level finer than its samples' spacing would
            filtered, resolved = antialiasing.filtered, antialiasing.resolved
            lod_bias = FILTERED_LOD_BIAS + math.log2(min(kx, ky)) if filtered else 0.0
        else:   # a still's sample is the frame's grid, shifted within its cells, averaged, never filtered
            filtered, resolved = False, (kx, ky) != (1, 1)
            subsample = grid_subsample(subsample, (kx, ky))
            lod_bias = subsample.lod_bias
        drawn = guarded(rect, size) if filtered else rect
        pose, matrix, moved = self._posed(camera, frame, drawn, state, subsample, window)
        cut = self.level_cut(camera, frame, lod_error_px if subsample is None else 0.0)
        culled = self.culler.cull(slot, matrix, size, drawn, cut)
        coarse = self._coarse(cut, matrix, size, drawn, pose)
        # A grid of samples: the same projection drawn over a viewport kx × ky times as large.
        target_size, target = (kx * size[0], ky * size[1]), Rect(kx * drawn.x, ky * drawn.y, kx * drawn.w, ky * drawn.h)
        backless = backless_batches(self, camera, frame, pose.bounds, lod_error_px if subsample is None else 0.0)
        tile = self._render(camera, target_size, target, matrix, culled, started, False, pose, moved=moved,
                            lod_bias=lod_bias, coarse=coarse, samples=antialiasing.samples, backless=backless)
        if not resolved:
            return dataclasses.replace(tile, rect=whole)
        resolving = time.perf_counter()
        pixels = resolve(tile.pixels, rect, drawn, (kx, ky), filtered)
        return dataclasses.replace(tile, rect=whole, pixels=pixels,
                                   render_ms=tile.render_ms + (time.perf_counter() - resolving) * 1e3)

    def use_tools(self, tools: ViewTools | None) -> None:
        """Draw with the frame's ``tools`` (clip planes, section box, highlight; None: none) from
        now on (:mod:`node.gl.view_tools`); the culler drops chunks they cut away. ValueError for
        tools that cannot be drawn (an unknown object, too many half-spaces)."""
        if self.view.use(tools):
            self._set_uniforms(self.view.uniforms())
            self.culler.set_clip(self.view.halfspaces if self.view.halfspaces.size else None)

    def pick(self, camera: Camera, size: tuple[int, int], x: int, y: int,
             state: SceneState | None = None) -> PickHit | None:
        """What the centre of pixel (``x``, ``y``) of the ``size`` frame sees in ``state``, cut by the
        tools in use: an id pass of that pixel alone (:mod:`node.gl.id_pass`); None: background."""
        if self._id_pass is None:
            self._id_pass = IdPass(self)
        return self._id_pass.pick(camera, size, x, y, state)

    def _set_uniforms(self, values: dict[str, Any]) -> None:
        for name, value in values.items():
            self._set_uniform(name, value)

    def pose_of(self, state: SceneState | None) -> ScenePose:
        """The pose of ``state``, kept for the next tiles of the same state."""
        if state is not self._pose[0]:
            self._pose = (state, self._base_pose if state is None else ScenePose.of(self.scene, state))
        return self._pose[1]

    def _coarse(self, cut: LodCut, matrix: np.ndarray, size: tuple[int, int], rect: Rect,
                pose: ScenePose) -> DrawRuns | None:
        """The runs of ``cut``'s coarse nodes that touch ``rect`` (None: full detail), but those of the
        batches ``pose`` moves or hides (they are drawn apart, at full detail)."""
        if not cut.coarse or self.lod is None:
            return None
        return self.lod.tile_runs(cut, matrix, size, rect, self.culler.clip, pose.skip)

    def _posed(self, camera: Camera, size: tuple[int, int], rect: Rect, state: SceneState | None,
               subsample: Subsample | None = None, window: Rect | None = None) -> tuple[ScenePose, np.ndarray,
                                                                                    DrawRuns]:
        """What every draw of ``rect`` in scene ``state`` starts from: the pose, the full-frame (4, 4)
        view-projection of its bounds (shifted by the ``subsample``'s offset: :func:`jitter_matrix`,
        so culling and drawing see the same frustum; narrowed to ``window``, of whose framebuffer
        ``rect`` then is a part: :func:`window_matrix`), and the runs of its moved objects that
        ``rect`` keeps."""
        pose = self.pose_of(state)
        offset = None if subsample is None else subsample.offset
        matrix = jitter_matrix(offset, size) @ view_projection(camera, size, pose.bounds)
        if window is not None:
            matrix, size = window_matrix(window, size) @ matrix, (window.w, window.h)
        moved = self.culler.cull_moved(matrix, size, rect, pose.whole, pose.models[pose.owner[list(pose.whole)]])
        return pose, matrix, moved

    def render_layer(self, camera: Camera, size: tuple[int, int], rect: Rect, chunk_ids: np.ndarray | None = None,
                     slot: Hashable | None = None, state: SceneState | None = None,
                     blend_apart: bool = False, subsample: Subsample | None = None,
                     lod_error_px: float = 0.0, window: Rect | None = None) -> RenderedTile:
        """A depth layer: the ``rect`` part of the ``size`` frame as :meth:`render_tile` draws it in
        scene ``state``, but of the chunks ``chunk_ids`` (K,) (sorted, unique; None: those the rect's
        culling keeps, ``slot`` naming it as there; of hidden ones nothing), and of moved objects
        what the rect's culling keeps where they are now (``blend_apart``: their blended batches left
        to :meth:`render_blend`), with its depth read back as well; ``subsample``, ``lod_error_px``
        and ``window`` as there (levels of detail are for layers that draw all of a scene's chunks
        they see: a sort-last share's)."""
        started = time.perf_counter()
        frame, whole = size, rect
        size, rect = windowed(size, rect, window)
        pose, matrix, moved = self._posed(camera, frame, rect, state, subsample, window)
        cut = self.level_cut(camera, frame, error_px := lod_error_px if subsample is None else 0.0)
        if chunk_ids is None:
            culled = self.culler.cull(tuple(whole.as_list()) if slot is None else slot, matrix, size, rect, cut)
        else:
            culled = self.culler.listed(chunk_ids, matrix, cut)
        tile = self._render(camera, size, rect, matrix, culled, started, with_depth=True, pose=pose, moved=moved,
                            blended_moved=False if blend_apart else None,
                            lod_bias=0.0 if subsample is None else subsample.lod_bias,
                            coarse=self._coarse(cut, matrix, size, rect, pose),
                            backless=backless_batches(self, camera, frame, pose.bounds, error_px, whole=True))
        return tile if window is None else dataclasses.replace(tile, rect=whole)

    def _render(self, camera: Camera, size: tuple[int, int], rect: Rect, matrix: np.ndarray, culled: TileCull,
                started: float, with_depth: bool, pose: ScenePose, moved: DrawRuns | None = None,
                blended_moved: bool | None = None, lod_bias: float = 0.0,
                coarse: DrawRuns | None = None, samples: int = 1, backless: np.ndarray | None = None) -> RenderedTile:
        """Draw ``culled`` in ``pose`` with the full-frame ``matrix`` scissored to ``rect`` and read the
        rect back (colour, and window depth when ``with_depth``); ``started`` is when the tile's work
        began; ``moved``: the runs of moved batches the tile keeps (None: those batches whole), of
        which ``blended_moved`` picks (:meth:`_draw`); textures read with ``lod_bias``; ``coarse``: the
        runs of coarse levels of detail to draw too (:class:`node.gl.lod_draws.LodDraws`); ``samples``
        multisamples (depth layers: always 1); ``backless``: (B,) the batches drawn without back faces."""
        width, height = size
        samples = 1 if with_depth else samples
        target = self.framebuffers.get((width, height), samples)
        gl_box = (rect.x, height - rect.y1, rect.w, rect.h)
        target.viewport = (0, 0, width, height)
        target.scissor = gl_box
        target.use()
        target.clear(*self._background, 1.0, depth=1.0, viewport=gl_box)
        self._use_camera(camera, lod_bias)
        self._draw(target, culled, pose, matrix, moved, blended_moved, coarse, backless)
        framebuffer = self.framebuffers.get((width, height))
        if samples > 1:
            framebuffer.viewport = (0, 0, width, height)
            framebuffer.scissor = gl_box
            framebuffer.use()
            self.ctx.copy_framebuffer(framebuffer, target)
        finish(self.ctx)
        drawn = time.perf_counter()
        data = framebuffer.read(viewport=gl_box, components=3, alignment=1)
        pixels = np.ascontiguousarray(np.frombuffer(data, np.uint8).reshape(rect.h, rect.w, 3)[::-1])
        depth = None
        if with_depth:
            data = framebuffer.read(viewport=gl_box, components=1, attachment=-1, alignment=1, dtype="f4")
            depth = np.ascontiguousarray(np.frombuffer(data, np.float32).reshape(rect.h, rect.w)[::-1])
        read = time.perf_counter()
        counts = self.culler.counts(culled, pose.skip if pose.skip.any() else None)
        moved_chunks, moved_triangles = ((pose.whole_chunks, pose.whole_triangles) if moved is None
                                         else (moved.chunks, moved.triangles))
        drawn_chunks = counts.chunks_drawn + moved_chunks
        coarse_triangles = 0 if coarse is None else coarse.triangles
        return RenderedTile(rect, pixels, (drawn - started) * 1e3, (read - drawn) * 1e3,
                            counts.triangles + moved_triangles + coarse_triangles, drawn_chunks,
                            self.scene.chunks.chunk_count - drawn_chunks, culled.cull_ms, culled.path, depth)

    def render_blend(self, camera: Camera, size: tuple[int, int], rect: Rect, chunk_ids: np.ndarray,
                     under: np.ndarray, state: SceneState | None = None,
                     subsample: Subsample | None = None, window: Rect | None = None) -> BlendedFragments:
        """Blended chunks ``chunk_ids`` (sorted, unique) in front of the layer :meth:`render_layer`
        has drawn of the same ``rect``, camera, size and ``state``, whose depth is ``under``
        (rect.h, rect.w) float32. Peeling: pass j keeps the fragments between the (j−1)-th depth
        and ``under`` and writes the nearest's depth, up to :data:`MAX_BLEND_LAYERS` layers; then
        for each m the fragments nearer than the (m+1)-th depth (the last m: than ``under``) are
        accumulated in draw order (:data:`BLEND_ACCUMULATE`) into a cleared buffer, as GL blends
        them over whatever the compositor finds behind them. Moved objects' blended batches are drawn
        with them, culled to ``rect`` where they are now (:meth:`render_layer` with ``blend_apart``
        leaves them out); ``subsample`` and ``window`` as the layer's."""
        started = time.perf_counter()
        frame = size
        size, rect = windowed(size, rect, window)
        pose, matrix, moved = self._posed(camera, frame, rect, state, subsample, window)
        culled = self.culler.listed(chunk_ids)
        framebuffer = self.framebuffers.get(size)
        gl_box = (rect.x, size[1] - rect.y1, rect.w, rect.h)
        framebuffer.scissor = gl_box
        framebuffer.use()
        self._use_camera(camera, 0.0 if subsample is None else subsample.lod_bias)
        self._set_uniform("u_origin", gl_box[:2])
        bounds = [self.ctx.texture((rect.w, rect.h), 1, dtype="f4") for _ in range(2)]
        for texture, unit in zip(bounds, (UNIT_FLOOR, UNIT_CEIL), strict=True):
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            texture.use(unit)
        depths: list[np.ndarray] = []
        layers: list[np.ndarray] = []
        try:
            self._peeling = True
            self._set_uniform("u_peel", True)
            self._blend_func = None
            framebuffer.color_mask = (False, False, False, False)
            floor = np.full(under.shape, -1.0, np.float32)
            bounds[1].write(under[::-1].tobytes())
            for _ in range(MAX_BLEND_LAYERS):
                bounds[0].write(floor[::-1].tobytes())
                framebuffer.clear(depth=1.0, viewport=gl_box)
                self._draw(framebuffer, culled, pose, matrix, moved, blended_moved=True)
                floor = self._read_depth(framebuffer, gl_box, rect)
                if not (floor < 1.0).any():
                    break
                depths.append(floor)
            framebuffer.color_mask = (True, True, True, True)
            self._blend_func = BLEND_ACCUMULATE
            bounds[0].write(np.full(under.shape, -1.0, np.float32).tobytes())
            for m in range(1, len(depths) + 1):
                ceiling = np.minimum(depths[m], under) if m < len(depths) else under
                bounds[1].write(np.ascontiguousarray(ceiling[::-1]).tobytes())
                framebuffer.clear(0.0, 0.0, 0.0, 0.0, depth=1.0, viewport=gl_box)
                self._draw(framebuffer, culled, pose, matrix, moved, blended_moved=True)
                data = framebuffer.read(viewport=gl_box, components=4, alignment=1)
                layers.append(np.frombuffer(data, np.uint8).reshape(rect.h, rect.w, 4)[::-1])
        finally:
            self._peeling = False
            self._set_uniform("u_peel", False)
            self._blend_func = BLEND_OVER
            framebuffer.color_mask = (True, True, True, True)
            for texture in bounds:
                texture.release()
        done = time.perf_counter()
        rgba = np.stack(layers) if layers else np.zeros((0, rect.h, rect.w, 4), np.uint8)
        depth = np.stack(depths) if depths else np.zeros((0, rect.h, rect.w), np.float32)
        triangles = self.culler.counts(culled, pose.skip if pose.skip.any() else None).triangles
        return BlendedFragments(np.ascontiguousarray(rgba[..., :3]), np.ascontiguousarray(rgba[..., 3]), depth,
                                triangles, (done - started) * 1e3, 0.0)

    @staticmethod
    def _read_depth(framebuffer: moderngl.Framebuffer, gl_box: tuple[int, int, int, int], rect: Rect) -> np.ndarray:
        """(rect.h, rect.w) float32 window depth of ``gl_box``, row 0 at the top."""
        data = framebuffer.read(viewport=gl_box, components=1, attachment=-1, alignment=1, dtype="f4")
        return np.ascontiguousarray(np.frombuffer(data, np.float32).reshape(rect.h, rect.w)[::-1])

    def render_frame(self, camera: Camera, size: tuple[int, int], state: SceneState | None = None,
                     subsample: Subsample | None = None, lod_error_px: float = 0.0) -> RenderedTile:
        """The whole ``size`` = (w, h) frame in scene ``state`` (None: the base pose), as
        ``subsample`` of a still (None: a plain frame, at the levels of detail within ``lod_error_px``)."""
        return self.render_tile(camera, size, Rect(0, 0, size[0], size[1]), state=state, subsample=subsample,
                                lod_error_px=lod_error_px)

    def render_still(self, camera: Camera, size: tuple[int, int], samples: StillPlan | int,
                     state: SceneState | None = None) -> np.ndarray:
        """The progressive still of ``samples`` (a :class:`StillPlan`, or a fixed count) of whole
        frames, each drawn as its sample's subsample, accumulated until it converged
        (:func:`tessera.scheduling.refinement.accumulate_still`): what the coordinator publishes as
        the still of a rested camera with the same plan; (h, w, 3) uint8."""
        plan = samples if isinstance(samples, StillPlan) else StillPlan(samples)
        return accumulate_still(lambda subsample: self.render_frame(camera, size, state, subsample).pixels,
                                size, plan).mean()

    def _draw(self, framebuffer: moderngl.Framebuffer, culled: TileCull, pose: ScenePose,
              view_proj: np.ndarray, moved: DrawRuns | None = None, blended_moved: bool | None = None,
              coarse: DrawRuns | None = None, backless: np.ndarray | None = None) -> None:
        """Issue the draw calls batch by batch in batch order (opaque and masked first, blended last),
        each with its object's matrices: one multi-draw-indirect over each culled batch's commands
        (without :attr:`multi_draw` one draw per index run), one draw per run of ``moved`` for a moved
        batch, or of the whole batch when ``moved`` is None, of those moved batches only the blended
        (``blended_moved`` True) or the others (False; None: all); then a batch's ``coarse`` runs of
        its levels of detail (:attr:`lod`'s commands); batches ``pose`` hides are left out. The culled
        and coarse runs of unmoved batches ``backless`` (B,) marks are drawn without back faces."""
        ctx = self.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        self.view.bind()
        self._blending = False
        if not self.multi_draw:
            assert culled.runs is not None, "GPU culling draws its commands by multi-draw-indirect"
        whole = pose.whole_runs(self.scene, moved)
        if blended_moved is not None:
            whole = {number: runs for number, runs in whole.items()
                     if (self.scene.batches[number].alpha_mode == "BLEND") == blended_moved}
        skip = pose.skip
        draws = [(number, CULLED, first, count) for number, first, count in culled.batches if not skip[number]]
        draws += [(number, WHOLE, 0, 0) for number in whole]
        if coarse is not None and self.lod is not None:
            draws += [(number, COARSE, first, count) for number, first, count in coarse.batch_slices()]
        draws.sort(key=lambda draw: (draw[0], draw[1]))
        model, culling = None, False
        for number, kind, first, count in draws:
            self._use_material(framebuffer, number)
            key = self._program_key(number)
            owner = int(pose.owner[number])
            if (moved_owner := owner if pose.moved[owner] else -1) != model:
                model = moved_owner
                self._use_model(pose, model, view_proj)
            culling = cull_back_faces(ctx, backless is not None and bool(backless[number]) and kind != WHOLE
                                      and moved_owner < 0, culling)
            if kind == WHOLE:
                vertex_array = self.shaders.vertex_arrays[key]
                for run_first, run_count in whole[number]:
                    vertex_array.render(moderngl.TRIANGLES, vertices=run_count, first=run_first)
                continue
            vertex_array, commands, runs = ((self.shaders.vertex_arrays[key], culled.commands, culled.runs)
                                            if kind == CULLED else (self.lod.vertex_arrays[key], self.lod.commands,
                                                                    coarse))  # type: ignore[union-attr]
            if self.multi_draw:
                draw_indirect(vertex_array, commands, moderngl.TRIANGLES, count, first)
                continue
            assert runs is not None
            for run in range(first, first + count):
                vertex_array.render(moderngl.TRIANGLES, vertices=int(runs.count[run]), first=int(runs.first[run]))
        if self._blending:
            framebuffer.depth_mask = True
            ctx.disable(moderngl.BLEND)
        cull_back_faces(ctx, False, culling)

    def _use_camera(self, camera: Camera, lod_bias: float = 0.0) -> None:
        """Set what shading takes from the camera (eye, key light) and the draw (the textures' LOD
        bias, of textured batches), and bind the environment."""
        self._set_uniform("u_lod_bias", lod_bias)
        self._set_uniform("u_light_direction", headlight_direction(camera))
        self._set_uniform("u_eye", tuple(float(v) for v in camera.eye))
        self._set_uniform("u_key_light", float(self.shading.key_light))
        for program in self.shaders.programs.values():
            self.lighting.use(program, UNIT_SPECULAR, UNIT_LUT)

    def _set_uniform(self, name: str, value: Any) -> None:
        """Set uniform ``name`` of the programs that have it."""
        self.shaders.set(name, value)

    def _program_key(self, number: int) -> tuple[ShaderVariant, bool]:
        """Batch ``number``'s program: its shader variant, with discards when it is alpha-masked or
        peeled. Without discards the depth test runs before the shader, so fragments behind what is
        drawn are not shaded (chunks come nearest first: :mod:`node.culling.order`)."""
        return self.shaders.key(number, self._peeling or self.view.discards
                                or self.scene.batches[number].alpha_mode == "MASK")

    def _use_model(self, pose: ScenePose, owner: int, view_proj: np.ndarray) -> None:
        """Set the matrices of object ``owner`` (−1: an unmoved one, drawn with ``view_proj`` as is)."""
        model = np.identity(4) if owner < 0 else pose.models[owner]
        matrix, normal = (view_proj, np.identity(3)) if owner < 0 else (view_proj @ model, pose.normals[owner])
        for program in self.shaders.programs.values():
            program["u_view_projection"].write(matrix.T.astype(np.float32).tobytes())
            program["u_model"].write(np.asarray(model).T.astype(np.float32).tobytes())
            program["u_normal_matrix"].write(normal.T.astype(np.float32).tobytes())

    def _use_material(self, framebuffer: moderngl.Framebuffer, number: int) -> None:
        """Set batch ``number``'s uniforms and texture; the first blended batch turns blending on
        (with :attr:`_blend_func`; None: it is drawn into depth as if opaque)."""
        batch = self.scene.batches[number]
        if batch.alpha_mode == "BLEND" and not self._blending and self._blend_func is not None:
            self._blending = True
            self.ctx.enable(moderngl.BLEND)
            self.ctx.blend_func = self._blend_func
            framebuffer.depth_mask = False
        key = self._program_key(number)
        program = self.shaders.programs[key]
        self.materials.use(program, key[0], batch)
        program["u_tint"].value = self.view.tint(number)
        if key[0].textured and key[0].uv_transform:
            self.shaders.use_uv_transforms(program, batch)

    def release(self) -> None:
        """Free the GL objects (the context stays the caller's)."""
        if self._owns_shared:
            self.shared.release()
        if self._id_pass is not None:
            self._id_pass.release()
        self.culler.release()
        self.materials.release()
        self.shaders.release()
        for resource in (self.index_buffer, self.vertex_buffer):
            resource.release()


def backless_batches(renderer: TileRenderer, camera: Camera, frame: tuple[int, int], bounds: np.ndarray,
                     error_px: float, whole: bool = False) -> np.ndarray | None:
    """The batches ``renderer`` draws without back faces in a ``frame`` at ``error_px``
    (:meth:`node.gl.lod_draws.LodDraws.back_culled`; None: none, as without levels, or with clip
    planes or discards)."""
    if renderer.lod is None or renderer.culler.clip is not None or renderer.view.discards:
        return None
    return renderer.lod.back_culled(camera, frame, bounds, error_px, whole)
