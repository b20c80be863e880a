"""Sort-last (issue 10: database decomposition): each node holds a share of the scene
(:mod:`tessera.decomposition.share_plan`); a frame is one whole-frame tile per share, drawn by the
node holding it, and the layers are merged by depth into one image. No balancer: a node joining
or leaving makes a new data partition, frames in flight are dropped, and frames start again once
every share of it is loaded. Tiles never move to another node (none other holds that share)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from tessera.balancers.base import Partition, ProjectedGroups, Tile
from tessera.compositing.depth_merge import merge_depth_tiles
from tessera.compositing.eye_dome import eye_dome
from tessera.decomposition.mode import DecompositionMode, SlotOf, ViewerTile
from tessera.decomposition.share_plan import ShareBook
from tessera.geometry import Rect
from tessera.scheduling.frame_jobs import FrameJob
from tessera.wire.codec import encode
from tessera.wire.depth_tiles import DecodedDepthTile, read_depth_tile
from tessera.wire.messages import DepthRequest, ShareSpec
from tessera.wire.protocol import NO_NODE_SLOT, ProtocolError, TileHeader


class SortLast(DecompositionMode):
    name = "sort-last"
    needs_depth = True
    tiles_move = False
    shares_data = True

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.shares = ShareBook()

    def partition(self, node_ids: Sequence[int], weights: dict[int, float], now: float,
                  groups: Callable[[], ProjectedGroups | None]) -> Partition:
        """One whole-frame tile per share of the newest data partition, to its holder."""
        assert self.shares.plan is not None
        frame = Rect(0, 0, *self.size)
        partition = Partition(tuple(Tile(frame, node_id) for node_id in self.shares.plan.holders))
        self.tiles.remember(partition)
        return partition

    def depth_request(self, partition: Partition) -> DepthRequest:
        assert self.shares.plan is not None
        return DepthRequest(mode="sort-last", share=self.shares.plan.version)

    @property
    def can_start(self) -> bool:
        return self.shares.complete

    def job_nodes(self) -> tuple[int, ...]:
        """Every holder of a share of the newest data partition, once all are loaded."""
        plan = self.shares.plan
        return tuple(plan.holders) if plan is not None and self.shares.complete else ()

    def nodes_changed(self, weights: Mapping[int, float]) -> dict[int, ShareSpec | None]:
        """A new data partition over the nodes of ``weights``, weighted by their speeds."""
        for node_id in list(self.shares.loaded):
            if node_id not in weights:
                self.shares.forget(node_id)
        plan = self.shares.repartition(weights)
        if plan is None:
            return {}
        return {node_id: ShareSpec(version=plan.version, index=index, weights=plan.weights)
                for index, node_id in enumerate(plan.holders)}

    def share_loaded(self, node_id: int, share: int | None) -> None:
        if share is not None:
            self.shares.share_loaded(node_id, share)

    def read_depth_tile(self, job: FrameJob, header: TileHeader, payload: bytes) -> DecodedDepthTile:
        """Pieces inside the tile (the frame; a render job's piece), drawn from the frame's data
        partition; ProtocolError if not."""
        assert job.depth is not None
        tile = read_depth_tile(payload, job.tiles[header.tile_id].rect, None, header.tile_id)
        if tile.version != job.depth.share:
            raise ProtocolError(f"depth tile drawn from the share of partition {tile.version}, the frame's is "
                                f"{job.depth.share}")
        return tile

    def viewer_tiles(self, job: FrameJob, slot_of: SlotOf) -> list[ViewerTile]:
        """The merge, one image of the tiles' rect (the frame; a render job's piece)."""
        tiles = [t.depth_tile for t in job.tiles if t.depth_tile is not None]
        area = job.tiles[0].rect
        if job.eye_dome is not None:     # a point cloud: shaded by EDL once merged (issue 36)
            color, depth = merge_depth_tiles(tiles, (area.w, area.h), self.background, with_depth=True,
                                             origin=(area.x, area.y))
            merged = eye_dome(color, depth, *job.eye_dome)
        else:
            merged = merge_depth_tiles(tiles, (area.w, area.h), self.background, origin=(area.x, area.y))
        return [(area, job.codec, NO_NODE_SLOT, encode(merged, job.codec, job.jpeg_quality))]

    def describe(self) -> dict[str, Any]:
        """The newest data partition (its version, shares, their holders and weights) and whether
        a share of it is still loading (frames wait)."""
        plan = self.shares.plan
        if plan is None:
            partition: dict[str, Any] = {"version": None, "shares": 0, "pending": True, "holders": [], "weights": []}
        else:
            partition = {"version": plan.version, "shares": len(plan.holders), "pending": not self.shares.complete,
                         "holders": list(plan.holders), "weights": [round(w, 4) for w in plan.weights]}
        return {"mode": self.name, "depth_strip": None, "partition": partition}
