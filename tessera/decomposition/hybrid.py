"""The hybrid sort-first/sort-last mode (seed 000 §4.4): the balancer's tiles as in sort-first,
but each chunk is drawn once, by the tile that owns it, into the tile grown by a border strip of
``strip`` px (:mod:`tessera.decomposition.chunk_ownership`: every node finds alone which chunks
its tile owns from the frame's whole partition). A node sends its tile's core as an image and the
rest with depth; the coordinator merges the strips by depth and shows each tile's core as sent
and the rest of the tile cut from the merge."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from tessera.balancers.base import Balancer, Partition
from tessera.compositing.depth_merge import merge_depth_tiles
from tessera.compositing.layers import ring_rects
from tessera.decomposition.chunk_ownership import exclusive_rect, readback_rect
from tessera.decomposition.mode import DecompositionMode, SlotOf, ViewerTile
from tessera.geometry import Rect
from tessera.scheduling.frame_jobs import FrameJob, check_payload_size
from tessera.wire.codec import Codec, encode
from tessera.wire.depth_tiles import DecodedDepthTile, read_depth_tile
from tessera.wire.messages import DepthRequest
from tessera.wire.protocol import TileHeader


class Hybrid(DecompositionMode):
    name = "hybrid"
    needs_depth = True

    def __init__(self, size: tuple[int, int], balancer: Balancer, background: np.ndarray, strip: int) -> None:
        super().__init__(size, balancer, background)
        self.strip = strip

    def depth_request(self, partition: Partition) -> DepthRequest:
        return DepthRequest(mode="hybrid", tiles=tuple(partition.rects), strip=self.strip)

    def read_depth_tile(self, job: FrameJob, header: TileHeader, payload: bytes) -> DecodedDepthTile:
        """Pieces inside the tile's read-back rect, the core inside the tile and holding what no
        other tile reaches, the core an image of the frame's codec; ProtocolError if not."""
        assert job.depth is not None
        rect, strip = job.tiles[header.tile_id].rect, job.depth.strip
        core_range = (exclusive_rect(rect, strip, job.size), rect)
        tile = read_depth_tile(payload, readback_rect(rect, strip, job.size), core_range, header.tile_id)
        if tile.core is not None:
            check_payload_size(tile.core[1], header.codec, tile.core[0])
        return tile

    def viewer_tiles(self, job: FrameJob, slot_of: SlotOf) -> list[ViewerTile]:
        decoded = [t.depth_tile for t in job.tiles if t.depth_tile is not None]
        merged = merge_depth_tiles(decoded, job.size, self.background)
        pieces = hybrid_frame_tiles([(t.rect, d) for t, d in zip(job.tiles, decoded, strict=True)], merged,
                                    job.codec, job.jpeg_quality)
        return [(rect, job.codec, slot_of(job.tiles[index].rendered_by), data) for rect, index, data in pieces]

    def describe(self) -> dict[str, Any]:
        return {"mode": self.name, "depth_strip": self.strip, "partition": None}


def hybrid_frame_tiles(tiles: Sequence[tuple[Rect, DecodedDepthTile]], merged: np.ndarray, codec: Codec,
                       quality: int) -> list[tuple[Rect, int, bytes]]:
    """What a hybrid frame shows, as (rect, index of the tile it belongs to, image in ``codec``):
    per tile (its rect, its depth tile) the core as the node sent it and the rest of its rect (the
    ring its neighbours' strips reach) cut from the ``merged`` (h, w, 3) uint8 frame and encoded.
    The rects cover the frame exactly, as the tiles do."""
    out: list[tuple[Rect, int, bytes]] = []
    for index, (rect, tile) in enumerate(tiles):
        regions = [rect]
        if tile.core is not None:
            out.append((tile.core[0], index, tile.core[1]))
            regions = ring_rects(rect, tile.core[0])
        for region in regions:
            pixels = np.ascontiguousarray(merged[region.y:region.y1, region.x:region.x1])
            out.append((region, index, encode(pixels, codec, quality)))
    return out
