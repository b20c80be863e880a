"""What a node draws into a depth layer in the hybrid and sort-last modes, and drawing it: the
node-side half of :mod:`tessera.compositing.depth_merge`.

- Hybrid (seed 000 §4.4, :mod:`tessera.decomposition.chunk_ownership`): tile ``index`` of the frame's tiles
  draws into its read-back rect (the tile grown by the depth strip) the chunks it owns and the
  shared ones touching it. The candidates are the chunks the rect's frustum keeps (the CPU tree of
  :mod:`node.culling.bvh`), so a node projects only the chunks near its tile; ownership depends on a
  chunk's own bound alone, so every node assigns each chunk alike without talking to the others.
  The plan names the tile's core too (:func:`tessera.decomposition.chunk_ownership.core_rect`), the part
  that needs no depth: all of a tile that a blended chunk touches, which is then drawn complete.
- Sort-last (:mod:`tessera.decomposition.data_partition`): a node draws the chunks of its share that the whole
  frame's frustum keeps, into the rect their projected bounds cover (IceT's bounding-box
  read-back); a share with nothing in view has no layer. A poster's piece (a render job's tile)
  is drawn the same way over the piece alone.
- Live (:func:`live_plan`): what a ``render`` message's depth request asks of a serving node. In
  sort-last the node holds only its share, so its share is all its chunks; its blended chunks are
  drawn apart, over its layer (:meth:`node.gl.renderer.TileRenderer.render_blend`), since their
  colour depends on what other shares draw behind them (a moved object's blended batches too);
  while the frame's scene state moves an object its chunk boxes no longer say where it is, so the
  whole frame is read back (moved objects are culled where they are now, as in every tile of the
  hybrid). :func:`render_plan` draws a plan.

The planners read no renderer: they take the scene's chunks as planning sees them
(:class:`PlanningScene`: boxes, the culler's tree, blended flags) and, live, the frame's pose;
only :func:`render_plan` draws. Chunk ids index the scene's chunks
(:class:`node.scene.chunks.SceneChunks`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.culling.bvh import ChunkBVH, covering_nodes, cull
from node.culling.frustum import frustum_planes_from_matrix
from node.gl.renderer import BlendedFragments, RenderedTile, TileRenderer
from node.scene.data import SceneData
from node.scene.pose import ScenePose
from tessera.balancers.projection import project_boxes
from tessera.compositing.layers import DepthLayer
from tessera.decomposition.chunk_ownership import assign_chunks, core_rect, readback_rect
from tessera.decomposition.data_partition import covering_rect
from tessera.geometry import Camera, Rect, view_projection
from tessera.scene.state import SceneState
from tessera.scheduling.refinement import Subsample
from tessera.wire.messages import DepthRequest

#: Most boxes a serving sort-last node projects to find the part of the frame its layer covers.
RECT_BOXES = 4096


@dataclass(frozen=True, eq=False)
class LayerPlan:
    """A depth layer to draw: its ``rect`` in the frame, ``chunk_ids`` (K,) int64 sorted, the
    ``exclusive`` part of it no other layer reaches (a hybrid tile's core, sent as colour alone;
    None: all of the layer carries depth), and ``blend_ids`` (sorted) blended chunks to draw apart
    over it (None: none; blended chunks are then among ``chunk_ids``, if any)."""

    rect: Rect
    chunk_ids: np.ndarray
    exclusive: Rect | None = None
    blend_ids: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class PlanningScene:
    """What planning reads of a loaded scene's C chunks and B batches: ``boxes`` (C, 2, 3) float64
    world chunk boxes at the base pose, ``tree`` the culler's chunk tree over them, ``bounds``
    (2, 3) float64 the scene's box (the near/far planes chunks are culled with), ``blended_batches``
    (B,) bool the batches that blend (glTF ``BLEND``) and ``blended`` (C,) bool the chunks of those."""

    boxes: np.ndarray
    tree: ChunkBVH
    bounds: np.ndarray
    blended_batches: np.ndarray
    blended: np.ndarray

    @classmethod
    def of(cls, scene: SceneData, tree: ChunkBVH) -> PlanningScene:
        """``scene``'s chunks with ``tree`` (:attr:`node.culling.tiles.TileCuller.bvh`) over them."""
        blends = np.array([batch.alpha_mode == "BLEND" for batch in scene.batches], dtype=bool)
        return cls(scene.chunks.boxes, tree, np.asarray(scene.bounds), blends, blends[scene.chunks.batch])


def visible_chunks(chunks: PlanningScene, camera: Camera, size: tuple[int, int], rect: Rect) -> np.ndarray:
    """(K,) int64 sorted ids of the chunks whose boxes touch ``rect``'s sub-frustum of the
    ``size`` frame (the culler's padded planes)."""
    planes = frustum_planes_from_matrix(view_projection(camera, size, chunks.bounds), size, rect)
    return cull(chunks.tree, planes).visible_chunks


def chunk_bounds(chunks: PlanningScene, chunk_ids: np.ndarray, camera: Camera, size: tuple[int, int]) -> np.ndarray:
    """(K, 4) float64 projected pixel bounds x0, y0, x1, y1 of chunks ``chunk_ids`` (K,), clipped to
    the frame (:func:`tessera.balancers.projection.project_boxes`)."""
    return project_boxes(chunks.boxes[chunk_ids].reshape(-1, 6), camera, size, chunks.bounds)


def hybrid_plan(chunks: PlanningScene, camera: Camera, size: tuple[int, int], tiles: Sequence[Rect], index: int,
                strip_px: int) -> LayerPlan:
    """Tile ``index`` of ``tiles`` (an exact cover of the ``size`` frame) in the hybrid mode with a
    ``strip_px`` border strip: its read-back rect, the chunks it draws and its core."""
    rect = readback_rect(tiles[index], strip_px, size)
    candidates = visible_chunks(chunks, camera, size, rect)
    ownership = assign_chunks(chunk_bounds(chunks, candidates, camera, size), tiles, strip_px, size,
                              blended=chunks.blended[candidates])
    core = core_rect(tiles[index], strip_px, size, bool(ownership.complete[index]))
    return LayerPlan(rect, candidates[ownership.draws[index]], core)


def sort_last_plan(chunks: PlanningScene, camera: Camera, size: tuple[int, int],
                   share: np.ndarray | None = None, area: Rect | None = None) -> LayerPlan | None:
    """The layer of a node holding chunks ``share`` (sorted ids; None: every chunk of ``chunks``,
    as a serving node holds only its share) over ``area`` of the frame (None: all of it; a
    poster's piece): those in view there and the part of it they project to; None when none is.
    A serving node's part is that of the chunk tree's nodes over them, :data:`RECT_BOXES` at most
    (it holds the chunks' own: projecting the 586k chunks of a 100M-triangle model's share took
    0.4-0.6 s of CPU a frame)."""
    area = Rect(0, 0, *size) if area is None else area
    planes = frustum_planes_from_matrix(view_projection(camera, size, chunks.bounds), size, area)
    culled = cull(chunks.tree, planes)
    drawn = culled.visible_chunks
    if share is None:
        nodes = covering_nodes(chunks.tree, culled.visible_first, culled.visible_end, RECT_BOXES)
        boxes = np.concatenate([chunks.tree.lo[nodes], chunks.tree.hi[nodes]], axis=1)
        bounds = project_boxes(boxes, camera, size, chunks.bounds)
    else:
        drawn = drawn[np.isin(drawn, share, assume_unique=True)]
        bounds = chunk_bounds(chunks, drawn, camera, size)
    rect = covering_rect(bounds, size)
    if rect is None:
        return None
    x0, y0, x1, y1 = max(rect.x, area.x), max(rect.y, area.y), min(rect.x1, area.x1), min(rect.y1, area.y1)
    return None if x1 <= x0 or y1 <= y0 else LayerPlan(Rect(x0, y0, x1 - x0, y1 - y0), drawn)


def live_plan(chunks: PlanningScene, pose: ScenePose, camera: Camera, size: tuple[int, int], request: DepthRequest,
              tile_id: int, area: Rect | None = None) -> LayerPlan | None:
    """The layer tile ``tile_id`` of a ``render`` message with depth ``request`` asks for, in scene
    ``pose`` (:meth:`node.gl.renderer.TileRenderer.pose_of` its state): a hybrid tile of
    ``request.tiles``, or (sort-last) the node's whole share over the tile's ``area`` (None: the
    whole frame, a live frame's one tile; a poster's piece); None: nothing of it in view. Raises
    ValueError for a tile id the request does not list."""
    if request.mode == "hybrid":
        if not 0 <= tile_id < len(request.tiles):
            raise ValueError(f"tile {tile_id} is not one of the frame's {len(request.tiles)} tiles")
        return hybrid_plan(chunks, camera, size, request.tiles, tile_id, request.strip)
    if pose.whole:
        area = Rect(0, 0, *size) if area is None else area
        plan: LayerPlan | None = LayerPlan(area, visible_chunks(chunks, camera, size, area))
    else:
        plan = sort_last_plan(chunks, camera, size, area=area)
    if plan is None:
        return None
    blends = chunks.blended[plan.chunk_ids]
    if not blends.any() and not chunks.blended_batches[list(pose.whole)].any():
        return plan
    return LayerPlan(plan.rect, plan.chunk_ids[~blends], blend_ids=plan.chunk_ids[blends])


def render_plan(renderer: TileRenderer, camera: Camera, size: tuple[int, int], plan: LayerPlan,
                state: SceneState | None, subsample: Subsample | None = None,
                lod_error_px: float = 0.0, window: Rect | None = None) -> tuple[RenderedTile, BlendedFragments | None]:
    """Draw ``plan`` in scene ``state`` (as ``subsample`` of a still; None: a plain frame, at the
    levels of detail within ``lod_error_px``; in a poster's ``window``, None: the whole frame's
    framebuffer): its layer (depth read back) and, when it has blended chunks apart, the blended
    fragments in front of that layer (moved objects' blended batches with them; None: no blend pass)."""
    apart = plan.blend_ids is not None
    layer = renderer.render_layer(camera, size, plan.rect, plan.chunk_ids, state=state, blend_apart=apart,
                                  subsample=subsample, lod_error_px=lod_error_px, window=window)
    if plan.blend_ids is None:
        return layer, None
    assert layer.depth is not None
    return layer, renderer.render_blend(camera, size, plan.rect, plan.blend_ids, layer.depth, state, subsample,
                                        window)


def as_depth_layer(tile: RenderedTile, slot: int) -> DepthLayer:
    """A rendered layer (depth read back) for the compositor, ties going to lower ``slot``."""
    if tile.depth is None:
        raise ValueError("this tile was rendered without depth (render_tile); use render_layer")
    return DepthLayer(tile.rect, tile.pixels, tile.depth, slot)
