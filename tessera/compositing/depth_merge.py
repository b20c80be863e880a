"""The depth merge (seed 000 §4.4's Z-buffer merge of the hybrid's strips; sort-last's whole-image
merge): depth layers and blended fragments into one frame, and what a frame of depth tiles
publishes. Conventions: :mod:`tessera.compositing.layers`."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from tessera.compositing.layers import FAR, BlendLayer, DepthLayer, pixel_view
from tessera.geometry import Rect
from tessera.wire.depth_tiles import DecodedDepthTile


def merge_by_depth(layers: Iterable[DepthLayer], size: tuple[int, int], background: np.ndarray,
                   exclusive: Iterable[tuple[Rect, np.ndarray]] = (), blends: Iterable[BlendLayer] = (),
                   depth_out: np.ndarray | None = None, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """(h, w, 3) uint8: ``layers`` merged by depth into a ``size`` = (w, h) frame (its top left
    pixel ``origin`` (x, y) of the frame the rects are in: a poster's piece), ``background``
    (3,) uint8 where none drew, the ``blends`` laid over it in slot order (at each pixel the
    accumulation of the m fragments in front of the merged depth: its colour + (255 − alpha) / 255
    × what is there, rounded), then the ``exclusive`` (rect, (rect.h, rect.w, 3) uint8 colour)
    pasted as they are: regions only one node drew (the hybrid's tile cores,
    :func:`tessera.decomposition.chunk_ownership.exclusive_rect`), which travel without depth and which the
    layers leave inactive. Layers are merged in slot order with a strict depth test, so a tie goes
    to the lower slot whatever order they came in; layers that share a slot (the pieces of one
    node's layer, :func:`split_layer`) must not overlap. Raises ValueError for a layer or region
    outside the frame or overlapping layers of one slot. The frame starts as the background, then
    O(summed layer pixels): depth by ``minimum``, colour by one masked copy of whole pixels
    (:func:`tessera.compositing.layers.pixel_view`)."""
    width, height = size
    if width <= 0 or height <= 0:
        raise ValueError(f"frame size must be positive, got {width}x{height}")
    ordered = sorted(layers, key=lambda item: item.slot)
    by_slot: dict[int, list[Rect]] = {}
    for layer in ordered:
        same = by_slot.setdefault(layer.slot, [])
        if any(layer.rect.intersection_area(other) for other in same):
            raise ValueError(f"layers of slot {layer.slot} overlap: each node's layer needs its own slot")
        same.append(layer.rect)
    depth = np.full((height, width), FAR, np.float32) if depth_out is None else depth_out   # (h, w): merged depth
    depth.fill(FAR)
    color = np.empty((height, width, 3), np.uint8)
    color[0] = np.asarray(background, np.uint8)
    color[1:] = color[0]   # whole rows: broadcasting the pixel over (h, w) is ~100x slower
    pixels = pixel_view(color)

    def placed(rect: Rect) -> Rect:
        return Rect(rect.x - origin[0], rect.y - origin[1], rect.w, rect.h)

    for layer in ordered:
        rect = placed(layer.rect)
        if rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
            raise ValueError(f"layer {rect.as_list()} lies outside the {width}x{height} frame")
        window = np.s_[rect.y:rect.y1, rect.x:rect.x1]
        wins = layer.depth < depth[window]
        np.minimum(depth[window], layer.depth, out=depth[window])
        np.copyto(pixels[window], pixel_view(layer.color), where=wins)
    for blend in sorted(blends, key=lambda item: item.slot):
        rect = placed(blend.rect)
        if rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
            raise ValueError(f"blend layer {rect.as_list()} lies outside the {width}x{height} frame")
        window = np.s_[rect.y:rect.y1, rect.x:rect.x1]
        count = (blend.depth < depth[window][None]).sum(axis=0)
        rows, columns = np.nonzero(count)
        layer = count[rows, columns] - 1
        under = color[window][rows, columns].astype(np.float32)
        through = (255.0 - blend.alpha[layer, rows, columns].astype(np.float32))[:, None] / np.float32(255.0)
        mixed = blend.color[layer, rows, columns].astype(np.float32) + through * under
        color[window][rows, columns] = np.minimum(np.rint(mixed), 255.0).astype(np.uint8)
    for frame_rect, region in exclusive:
        rect = placed(frame_rect)
        if rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height or region.shape != (rect.h, rect.w, 3):
            raise ValueError(f"exclusive region {rect.as_list()} with colour {region.shape} does not fit the "
                             f"{width}x{height} frame")
        color[rect.y:rect.y1, rect.x:rect.x1] = region
    return color


def merge_depth_tiles(tiles: Sequence[DecodedDepthTile], size: tuple[int, int], background: np.ndarray,
                      with_depth: bool = False, origin: tuple[int, int] = (0, 0)) -> Any:
    """(h, w, 3) uint8: every tile's layers merged by depth over the ``size`` frame (at ``origin``
    of theirs, :func:`merge_by_depth`), ``background``
    (3,) uint8 where none drew, their blend layers laid over it
    (:func:`merge_by_depth`); ``with_depth``: (that, the merged window depth (h, w) float32). Cores
    are not pasted: they are published as they came (:func:`tessera.decomposition.hybrid.hybrid_frame_tiles`)."""
    depth = np.empty((size[1], size[0]), np.float32) if with_depth else None
    color = merge_by_depth([layer for tile in tiles for layer in tile.layers], size, background,
                           blends=[blend for tile in tiles for blend in tile.blends], depth_out=depth, origin=origin)
    return (color, depth) if with_depth else color
