"""The one small interface of a decomposition mode (Equalizer's one technique per file): what a
frame is cut into and who may draw each part, what a render message asks of the nodes, what a
node's tile must be and how it is read, and what viewers get of a complete frame.

The scheduler holds one mode and asks it; it has no mode of its own. Modes: :mod:`.sort_first`
(the default), :mod:`.hybrid` (seed 000 §4.4), :mod:`.sort_last` (database decomposition).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from tessera.balancers.base import Balancer, Partition, ProjectedGroups, TileTiming
from tessera.decomposition.balanced_tiles import BalancedTiles
from tessera.geometry import Rect
from tessera.scheduling.frame_jobs import FrameJob, check_payload_size
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.messages import DepthRequest, ShareSpec
from tessera.wire.protocol import TileHeader

#: What viewers get of a frame: (rect, codec, node slot, image bytes) per piece, covering it.
ViewerTile = tuple[Rect, Codec, int, bytes]
#: A node's slot as viewers see it, from its id (:data:`tessera.wire.protocol.NO_NODE_SLOT` if gone).
SlotOf = Callable[[int | None], int]


class DecompositionMode(ABC):
    """One decomposition of a ``size`` = (w, h) frame. Every mode keeps the chosen balancer
    (:class:`BalancedTiles`; sort-last keeps it for the stats and for a switch of mode later)."""

    name: ClassVar[str]
    #: Nodes must render depth tiles (a node without that capability is refused).
    needs_depth: ClassVar[bool] = False
    #: Any ready node can draw any tile: a straggler's tiles may be backed up, a failed one moved.
    tiles_move: ClassVar[bool] = True
    #: Each node holds a share of the scene that follows the node set (:meth:`nodes_changed`).
    shares_data: ClassVar[bool] = False

    def __init__(self, size: tuple[int, int], balancer: Balancer, background: np.ndarray) -> None:
        """``background``: (3,) uint8, painted where no layer drew (depth modes)."""
        self.size = size
        self.tiles = BalancedTiles(balancer, size)
        self.background = background

    def resize(self, size: tuple[int, int]) -> None:
        """Frames from now on are ``size`` (w, h) px; the partition history starts anew."""
        self.size = self.tiles.size = size
        self.tiles.set_balancer(self.tiles.balancer)

    # ----------------------------------------------------------------- partition
    def partition(self, node_ids: Sequence[int], weights: dict[int, float], now: float,
                  groups: Callable[[], ProjectedGroups | None]) -> Partition:
        """The frame's tiles over the ready ``node_ids`` with their speed ``weights``; ``groups``
        projects the frame's primitive groups when the balancer uses them."""
        return self.tiles.partition(node_ids, weights, now, groups() if self.tiles.balancer.uses_groups else None)

    def depth_request(self, partition: Partition) -> DepthRequest | None:
        """What a frame of ``partition`` asks of the nodes beyond plain tiles (None: nothing)."""
        return None

    @property
    def can_start(self) -> bool:
        """Frames may start (sort-last: every share of the newest data partition is loaded)."""
        return True

    def job_nodes(self) -> tuple[int, ...] | None:
        """The nodes that each draw every tile of a render job (sort-last: a share each, merged by
        depth; empty: none now, a share still loading); None: any one node holding the scene does."""
        return None

    def take_timings(self, frame_id: int, timings: tuple[TileTiming, ...]) -> bool:
        """An interactive frame's tile timings for the next partition; True when taken."""
        return self.tiles.take_timings(frame_id, timings)

    # ----------------------------------------------------------------- nodes
    def nodes_changed(self, weights: Mapping[int, float]) -> dict[int, ShareSpec | None] | None:
        """The node set is now ``weights``' keys (with their speeds). None: the partition does not
        hang on it (a node that joins loads the whole scene); else what each node must load of the
        new data partition (frames in flight belong to the old one)."""
        return None

    def share_loaded(self, node_id: int, share: int | None) -> None:  # noqa: B027 - a hook only sort-last needs
        """Node ``node_id`` loaded its part (sort-last: its share of partition ``share``)."""

    # ----------------------------------------------------------------- tiles and frames
    def read_tile(self, job: FrameJob | None, header: TileHeader, payload: bytes) -> DecodedDepthTile | None:
        """Check a tile's bytes against what its frame ``job`` (None: dropped) expects; a depth
        tile of a depth frame decoded (None otherwise: a plain tile is kept as its bytes).
        ProtocolError when they are not what they claim."""
        if not header.depth:
            check_payload_size(payload, header.codec, header.rect)
            return None
        if job is None or job.depth is None or not 0 <= header.tile_id < len(job.tiles):
            return None   # a dropped frame's tile, or one the scheduler refuses
        return self.read_depth_tile(job, header, payload)

    def read_depth_tile(self, job: FrameJob, header: TileHeader, payload: bytes) -> DecodedDepthTile | None:
        """A depth tile of ``job``'s, checked and decoded (depth modes)."""
        return None

    @property
    def merges(self) -> bool:
        """Frames are merged on the coordinator before they are shown."""
        return self.needs_depth

    def viewer_tiles(self, job: FrameJob, slot_of: SlotOf) -> list[ViewerTile]:
        """What viewers get of complete frame ``job``: its tiles as the nodes sent them."""
        return [(t.rect, job.codec, slot_of(t.rendered_by), t.payload or b"") for t in job.tiles]

    @abstractmethod
    def describe(self) -> dict[str, Any]:
        """The mode's part of ``/api/stats``: ``mode``, ``depth_strip`` (None outside the hybrid),
        ``partition`` (None outside sort-last)."""
