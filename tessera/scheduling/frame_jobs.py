"""Frames in flight: which tile each node owes, what has arrived, and the checks that keep a
published frame whole (every tile, one camera, one scene state, the right size).

Pure bookkeeping (no sockets, no clocks: times are passed in), so it is tested directly. The
payload bytes are opaque here; :func:`check_payload_size` is the coordinator's cheap check of
them before a tile is accepted.
"""

from __future__ import annotations

import io
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

from PIL import Image

from tessera.balancers.base import Partition, TileTiming
from tessera.geometry import Camera, Rect
from tessera.scene.state import SceneState, StateDelta
from tessera.scheduling.refinement import ONE_FRAME, StillPlan, Subsample
from tessera.scheduling.render_jobs import JobItem
from tessera.tools.clipping import ClipState
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.messages import DepthRequest, Render, RenderTile
from tessera.wire.protocol import NODE_PHASES, ProtocolError, TileHeader, state_tag

#: The session every coordinator has, made at start-up from its ``--scene`` and ``--size``.
DEFAULT_SESSION = "default"

#: A node's part of a complete frame: phases (ms), tiles, read-back rects, counters.
NodeRollup = tuple[dict[str, float], list[list[int]], list[list[int]], dict[str, float | str]]


@dataclass
class TileJob:
    """One tile of a frame: assigned node (None while waiting to be pulled), result when back.
    ``earlier``: nodes it was assigned to before a backup copy went to ``node_id``; the first copy
    back wins. ``depth_tile``: a depth tile's decoded layers, set by the coordinator when it
    accepts one (the payload then holds its bytes). ``part_of``: the balancer's tile this one is a
    piece of (a display wall's cut, :meth:`tessera.decomposition.wall_cells.WallLayout.pieces`;
    None: a whole tile)."""

    tile_id: int
    rect: Rect
    node_id: int | None
    earlier: set[int] = field(default_factory=set)
    header: TileHeader | None = None
    payload: bytes | None = None
    rendered_by: int | None = None
    send_ms: float | None = None
    counters: dict[str, float | str] = field(default_factory=dict)
    depth_tile: DecodedDepthTile | None = None
    part_of: Rect | None = None

    @property
    def done(self) -> bool:
        return self.payload is not None

    @property
    def drawn(self) -> Rect:
        """What a node draws for this tile: the tile it is a piece of, with the pieces sent beside it."""
        return self.rect if self.part_of is None else self.part_of


@dataclass
class FrameJob:
    """A frame being rendered: one camera, one scene ``state`` (None: the base pose, a scene whose
    nodes reported no objects), one partition, every tile tracked.

    ``still``: the lossless frame rendered once motion stopped (else an interactive frame), sample
    ``sample`` (0-based) of a progressive still sampled as ``plan`` says (:mod:`tessera.scheduling.refinement`);
    ``version``: the scheduler's state version it shows, ``changed_at`` when that state arrived
    (seconds, the scheduler's clock); ``inputs``: each viewer's newest input sequence number
    it accounts for; ``depth``: the hybrid or sort-last request its tiles are rendered with (None:
    sort-first), its tiles then depth tiles; ``ahead``: started while no node holding its scene was
    idle, for one ending its last tile (dispatch ahead); ``one_by_one``: its tiles are pieces of
    the frame that go to a node one at a time, the next when the one before came back (a pull
    frame: an idle node holding the scene takes one too); ``clip`` and ``highlight``: the
    session's clip planes and section box and its selected object when it started (issue 35);
    ``job``: the render job (a poster, a film: :mod:`tessera.scheduling.render_jobs`) whose
    ``item`` it draws, in ``window`` (None: the whole frame's framebuffer).
    """

    frame_id: int
    camera: Camera
    size: tuple[int, int]
    codec: Codec
    jpeg_quality: int
    pull: bool
    tiles: list[TileJob]
    started_at: float
    pull_queue: deque[int] = field(default_factory=deque)
    partition: Partition | None = None
    still: bool = False
    version: int = 0
    changed_at: float = 0.0
    inputs: dict[object, int] = field(default_factory=dict)
    state: SceneState | None = None
    depth: DepthRequest | None = None
    session: str = DEFAULT_SESSION
    scene: str | None = None
    tiles_done: int = 0
    sends_done: int = 0
    ahead: bool = False
    one_by_one: bool = False
    sample: int = 0
    plan: StillPlan = ONE_FRAME
    clip: ClipState | None = None
    highlight: str | None = None
    #: Its levels-of-detail bound, px (None: full detail; stills always are).
    lod_error_px: float | None = None
    #: A point cloud's frame (issue 36): its point budget (None: a still's, every point in view down
    #: to its spacing on screen), a still's spacing on screen (px; 0: every point in view; None: the
    #: node's default), the smallest splat side (px) and, where the coordinator shades the merged
    #: frame (sort-last), near and far.
    point_budget: int | None = None
    point_spacing_px: float | None = None
    point_size: float | None = None
    eye_dome: tuple[float, float] | None = None
    job: str | None = None
    item: JobItem | None = None
    window: Rect | None = None
    #: A job tile's expected node time (ms): what its piece took last (None: not known).
    expected_ms: float | None = None

    @classmethod
    def create(cls, frame_id: int, camera: Camera, size: tuple[int, int], codec: Codec, jpeg_quality: int,
               partition: Partition, started_at: float, *, still: bool = False, version: int = 0,
               changed_at: float = 0.0, inputs: dict[object, int] | None = None,
               state: SceneState | None = None, depth: DepthRequest | None = None,
               session: str = DEFAULT_SESSION, scene: str | None = None, sample: int = 0,
               plan: StillPlan = ONE_FRAME, parts: Sequence[Rect | None] = (), clip: ClipState | None = None,
               highlight: str | None = None) -> FrameJob:
        """``parts``: for each tile of ``partition``, the tile it is a piece of (empty: none is)."""
        parts = parts or [None] * len(partition.tiles)
        tiles = [TileJob(i, t.rect, None if partition.pull else t.node_id, part_of=part)
                 for i, (t, part) in enumerate(zip(partition.tiles, parts, strict=True))]
        job = cls(frame_id, camera, size, codec, jpeg_quality, partition.pull, tiles, started_at,
                  partition=partition, still=still, version=version, changed_at=changed_at,
                  inputs=dict(inputs or {}), state=state, depth=depth, session=session, scene=scene,
                  sample=sample, plan=plan, clip=clip, highlight=highlight)
        if partition.pull:
            job.pull_queue.extend(range(len(tiles)))
        return job

    @property
    def complete(self) -> bool:
        return self.tiles_done == len(self.tiles)

    @property
    def samples(self) -> int:
        """The most samples of its still (1: a frame not accumulated)."""
        return self.plan.most

    @property
    def subsample(self) -> Subsample | None:
        """How its tiles are drawn: a still's sample's jitter and LOD bias (None: a plain frame)."""
        return self.plan.subsample(self.sample) if self.still else None

    @property
    def timings_complete(self) -> bool:
        """Every tile arrived and its send time too (counted, O(1): asked on every ``tile_sent``)."""
        return self.complete and self.sends_done == len(self.tiles)

    def render_message(self, tile_ids: list[int], state: SceneState | StateDelta | None = None) -> Render:
        """The ``render`` control message for some of this frame's tiles; ``state`` brings the node
        to this frame's state (the state itself, or a delta on the one the node has)."""
        sub = self.subsample
        return Render(frame=self.frame_id, camera=self.camera, size=self.size, codec=self.codec,
                      jpeg_quality=self.jpeg_quality,
                      tiles=tuple(RenderTile(tile=i, rect=self.tiles[i].rect, part_of=self.tiles[i].part_of)
                                  for i in tile_ids), state=state,
                      depth=self.depth, scene=self.scene, jitter=None if sub is None else sub.offset,
                      lod_bias=None if sub is None else sub.lod_bias, clip=self.clip, highlight=self.highlight,
                      lod_error_px=self.lod_error_px, window=self.window, point_budget=self.point_budget,
                      point_spacing_px=self.point_spacing_px, point_size=self.point_size)

    def pull_next(self) -> list[int]:
        """The next tiles to pull (tile rotation): the head of the pull queue, with the pieces of the
        same tile right after it (a node draws them as one)."""
        first = self.pull_queue.popleft()
        part = self.tiles[first].part_of
        pulled = [first]
        while part is not None and self.pull_queue and self.tiles[self.pull_queue[0]].part_of == part:
            pulled.append(self.pull_queue.popleft())
        return pulled

    def busy_ms(self, tile_id: int, header: TileHeader) -> float:
        """How long the node that sent tile ``tile_id`` (``header``) worked before it could: its
        phases, and for a piece of a tile the rest of the tile's drawing too (the pieces' render and
        read-back are the tile's in proportion to area; the node drew them before sending the first)."""
        tile = self.tiles[tile_id]
        drawn = header.render_ms + header.readback_ms
        return drawn * tile.drawn.area / tile.rect.area + header.encode_ms

    def accept(self, node_id: int, header: TileHeader, payload: bytes,
               depth_tile: DecodedDepthTile | None = None) -> TileJob | None:
        """Record a tile result after checking it is the tile this node owes; ProtocolError if not.
        None: the second copy of a tile that was also given to another node (dropped). The payload
        is kept as it is (see :func:`check_payload_size`); a depth frame's tiles come with their
        ``depth_tile`` decoded."""
        if not 0 <= header.tile_id < len(self.tiles):
            raise ProtocolError(f"frame {self.frame_id} has no tile {header.tile_id}")
        tile = self.tiles[header.tile_id]
        if tile.node_id != node_id and node_id not in tile.earlier:
            raise ProtocolError(f"tile {header.tile_id} of frame {self.frame_id} was not assigned to this node")
        if header.rect != tile.rect:
            raise ProtocolError(
                f"tile {header.tile_id} has rect {header.rect.as_list()}, expected {tile.rect.as_list()}")
        if header.codec != self.codec:
            raise ProtocolError(f"tile codec {header.codec.name} but {self.codec.name} was requested")
        if header.depth != (self.depth is not None) or (depth_tile is None) == header.depth:
            mode = "sort-first" if self.depth is None else self.depth.mode
            raise ProtocolError(f"tile {header.tile_id} of frame {self.frame_id} is "
                                f"{'' if header.depth else 'not '}a depth tile; the frame's mode is {mode}")
        expected = state_tag(None if self.state is None else self.state.version)
        if header.state != expected:
            raise ProtocolError(f"tile {header.tile_id} of frame {self.frame_id} shows scene state {header.state}, "
                                f"the frame's is {expected}")
        if tile.done:
            if tile.rendered_by == node_id:
                raise ProtocolError(f"tile {header.tile_id} of frame {self.frame_id} was already received")
            return None
        tile.header, tile.payload, tile.rendered_by, tile.depth_tile = header, payload, node_id, depth_tile
        self.tiles_done += 1
        return tile

    def record_send(self, node_id: int, tile_id: int, send_ms: float,
                    counters: dict[str, float | str] | None = None) -> None:
        """The node's ``tile_sent``: send time (ms) and its per-tile counters (e.g. triangles drawn)."""
        if 0 <= tile_id < len(self.tiles) and self.tiles[tile_id].rendered_by == node_id:
            tile = self.tiles[tile_id]
            self.sends_done += tile.send_ms is None
            tile.send_ms = send_ms
            tile.counters = dict(counters or {})

    def counters_by_node(self) -> dict[int, dict[str, float | str]]:
        """Per-node sums of the tiles' numeric counters (text counters: the last tile's value)."""
        out: dict[int, dict[str, float | str]] = {}
        for tile in self.tiles:
            if tile.rendered_by is None:
                continue
            sums = out.setdefault(tile.rendered_by, {})
            for key, value in tile.counters.items():
                previous = sums.get(key, 0)
                if isinstance(value, str) or isinstance(previous, str):
                    sums[key] = value
                else:
                    sums[key] = previous + value
        return out

    def readback_by_node(self) -> dict[int, list[list[int]]]:
        """Per node, where it drew in this frame ([x, y, w, h] each): a tile's rect, a depth tile's
        extent (none when it drew nothing)."""
        out: dict[int, list[list[int]]] = {}
        for tile in self.tiles:
            extent = tile.rect if tile.depth_tile is None else tile.depth_tile.extent
            if tile.rendered_by is not None and extent is not None:
                out.setdefault(tile.rendered_by, []).append(extent.as_list())
        return out

    def ms_per_px_by_node(self) -> dict[int, float]:
        """Each node's busy ms per pixel (render + read-back + encode) in this frame: what a tile
        of it is expected to take, for spotting stragglers."""
        busy: dict[int, list[float]] = {}
        for tile in self.tiles:
            if tile.header is not None and tile.rendered_by is not None:
                spent = busy.setdefault(tile.rendered_by, [0.0, 0.0])
                spent[0] += tile.header.render_ms + tile.header.readback_ms + tile.header.encode_ms
                spent[1] += tile.rect.area
        return {node_id: ms / pixels for node_id, (ms, pixels) in busy.items() if pixels > 0}

    def rollup_by_node(self, timings: tuple[TileTiming, ...]) -> dict[int, NodeRollup]:
        """Per node of a complete frame with its ``timings``: its summed phases (ms, by
        :data:`tessera.wire.protocol.NODE_PHASES`), its tiles and where it drew ([x, y, w, h]
        each), its counters (:meth:`counters_by_node`)."""
        phases: dict[int, dict[str, float]] = {}
        rects: dict[int, list[list[int]]] = {}
        for t in timings:
            sums = phases.setdefault(t.node_id, dict.fromkeys(NODE_PHASES, 0.0))
            for phase, ms in zip(NODE_PHASES, t.phase_ms, strict=True):
                sums[phase] += ms
            rects.setdefault(t.node_id, []).append(t.rect.as_list())
        counters = self.counters_by_node()
        readback = self.readback_by_node()
        return {node_id: (sums, rects[node_id], readback.get(node_id, []), counters.get(node_id, {}))
                for node_id, sums in phases.items()}

    def owed_by(self, node_id: int) -> list[int]:
        """Tiles assigned to ``node_id`` and not back yet (earlier owners of a backed-up tile owe none)."""
        return [t.tile_id for t in self.tiles if t.node_id == node_id and not t.done]

    def timings(self) -> tuple[TileTiming, ...]:
        """Per-tile measured phases (ms) of a complete frame, attributed to the node that rendered each."""
        out = []
        for tile in self.tiles:
            assert tile.header is not None and tile.rendered_by is not None
            out.append(TileTiming(tile.rect, tile.rendered_by, tile.header.render_ms, tile.header.readback_ms,
                                  tile.header.encode_ms, tile.send_ms or 0.0))
        return tuple(out)


def check_late_tile(header: TileHeader, asked: tuple[Codec, list[Rect]] | None) -> None:
    """A tile of a frame out of flight against what its frame asked (``asked``: its codec and each
    tile's rect; None: forgotten, nothing to check); ProtocolError when it is not that tile."""
    if asked is None:
        return
    codec, rects = asked
    if not 0 <= header.tile_id < len(rects):
        raise ProtocolError(f"frame {header.frame_id} had no tile {header.tile_id}")
    if header.rect != rects[header.tile_id]:
        raise ProtocolError(f"tile {header.tile_id} has rect {header.rect.as_list()}, "
                            f"expected {rects[header.tile_id].as_list()}")
    if header.codec != codec:
        raise ProtocolError(f"tile codec {header.codec.name} but {codec.name} was requested")


def check_payload_size(payload: bytes, codec: Codec, rect: Rect) -> None:
    """A tile's bytes decode to an image of ``rect``'s size, checked when the tile arrives so that no
    published frame holds a tile that cannot be shown: raw length; the image header's format and
    dimensions; then a decode — JPEG at 1/8 scale (libjpeg-turbo's DCT scaling: it reads every
    entropy-coded segment, about 0.2 ms for a 427x720 tile), PNG whole (still frames, rarely)."""
    if codec is Codec.RAW:
        if len(payload) != rect.w * rect.h * 3:
            raise ProtocolError(f"raw tile of {len(payload)} bytes, expected {rect.w * rect.h * 3}")
        return
    try:
        with Image.open(io.BytesIO(payload)) as image:
            size, fmt = image.size, image.format
            if fmt == codec.name and size == (rect.w, rect.h):
                if codec is Codec.JPEG:
                    image.draft("RGB", (max(rect.w // 8, 1), max(rect.h // 8, 1)))
                image.load()
    except Exception as exc:
        raise ProtocolError(f"tile payload is not a readable {codec.name}: {' '.join(str(exc).split())[:200]}") \
            from None
    if fmt != codec.name:
        raise ProtocolError(f"tile payload is {fmt}, expected {codec.name}")
    if size != (rect.w, rect.h):
        raise ProtocolError(f"tile image is {size[0]}x{size[1]}, expected {rect.w}x{rect.h}")
