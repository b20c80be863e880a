"""JSON control messages between render nodes, the coordinator and viewers: the catalogue.

Every message is a frozen pydantic model whose ``kind`` is its JSON ``type``. :meth:`Message.to_json`
gives the JSON object, :meth:`Message.from_json` validates one (:class:`InvalidMessage`, naming the
field, when it is wrong) and :func:`parse` decodes text: at most :data:`MAX_JSON_BYTES`, no NaN or
Infinity, an object whose ``type`` is one the caller accepts. Fields a side does not know are
ignored, so peers may send more than the catalogue holds (older nodes still send
``capabilities.codecs`` and ``scene_ready``'s ``meshes``, ``chunks`` and ``load_ms``). Optional
fields are left out of the JSON where they are None, so messages without them are what they were
before the fields existed.
Binary tiles and frames, and the protocol version, are in :mod:`tessera.wire.protocol`.

node → coordinator

* ``hello`` :class:`NodeHello` — the first message: name, token, GL renderer, protocol version,
  capabilities (slowdown, calibrate, depth)
* ``scene_progress`` :class:`SceneProgress`, ``scene_ready`` :class:`SceneReady` (the scene spec
  loaded, triangles, bounds, world-space primitive groups, the named objects and the animations'
  keyframes; in sort-last, the data partition version of the share loaded), ``scene_error``
  :class:`SceneError`
* ``levels_ready`` :class:`LevelsReady` — the scene's levels of detail are built and held: frames
  may ask for a levels-of-detail bound
* ``tile_sent`` :class:`TileSent` — after each binary tile: its send time and the node's per-tile
  counters (triangles, chunks_drawn, chunks_culled, cull_ms, cull_path)
* ``render_error`` :class:`RenderError` — a tile the node could not render (frame 0, tile 0: a
  failed calibration)
* ``tiles_dropped`` :class:`TilesDropped` — tiles of a cancelled frame skipped unrendered
* ``calibration`` :class:`Calibration` — answer to ``calibrate``: the best of ``repeats`` renders
  of ``rect``, no output sent, slowdown included

coordinator → node

* ``welcome`` :class:`Welcome` (node id), ``load_scene`` :class:`LoadScene` (in sort-last, with the
  node's ``share`` of the scene: :class:`ShareSpec`; sent again when the data is re-partitioned;
  with ``sha256`` and ``url``, where a node that cannot open the scene file fetches it). A node
  holds several scenes at once (issue 19: sessions)
* ``render`` :class:`Render` — tiles of the ``scene`` named (None: the scene loaded last) are
  rendered in list order, each sent as soon as done, in the message's scene ``state`` (a full
  state, or a delta on the one the node was sent last); with ``depth`` (:class:`DepthRequest`,
  issue 10) as depth tiles of the hybrid or sort-last mode; pieces of one tile cut at a display
  wall's cell edges (:class:`RenderTile` ``part_of``) drawn as one; cut by the session's ``clip``
  planes and section box, its selected object tinted (``highlight``, issue 35)
* ``calibrate`` :class:`Calibrate` (seed 003 §1), of a ``scene`` likewise, in order with renders
* ``cancel`` :class:`Cancel` — the frames were superseded: skip their tiles not begun yet

coordinator → viewer: ``hello`` :class:`ViewerHello`, ``camera`` :class:`CameraUpdate` (another
viewer or the API moved it), ``scene`` :class:`ViewerScene` (the first node loaded it), ``error``
:class:`ViewerError` (the viewer's input was refused).

viewer → coordinator: ``camera`` :class:`CameraUpdate` (with ``seq``, the viewer's input number),
``latency`` :class:`LatencyReport` (the viewer's own input → display figures).

A peer that breaks the protocol is closed with code 1008 (policy) or 4401 (bad token) and a reason.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Annotated, Any, ClassVar, Literal, Self, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PlainSerializer,
    PlainValidator,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
    model_validator,
)

from tessera.geometry import Camera, Rect
from tessera.scene.state import SceneState, StateDelta, state_from_json
from tessera.tools.clipping import ClipState
from tessera.wire.codec import Codec
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError

MAX_JSON_BYTES = 1 << 20
#: Largest frame side (px) a ``render`` or ``calibrate`` may ask for.
MAX_SIDE = 16384
MAX_INPUT_SEQ = 2**32 - 1
MAX_CALIBRATION_REPEATS = 20
#: Longest counter name and text value in ``tile_sent.stats``.
MAX_COUNTER_TEXT = 40
#: Longest reason a ProtocolError of this module gives.
MAX_REASON = 300
#: Most tiles a hybrid ``render`` may list, and most shares a sort-last partition may have.
MAX_DEPTH_TILES = 4096
#: Largest smallest splat side (px) a ``render`` may ask for (issue 36).
MAX_POINT_SIZE = 24.0
#: Longest ``load_scene.url``.
MAX_URL = 2048


class InvalidMessage(ProtocolError):
    """A JSON object of a known ``kind`` whose fields are wrong; ``data`` is that object."""

    def __init__(self, reason: str, kind: str, data: Any) -> None:
        super().__init__(reason)
        self.kind, self.data = kind, data


def _camera(value: Any) -> Camera:
    return value if isinstance(value, Camera) else Camera.from_json(value)


def _rect(value: Any) -> Rect:
    if isinstance(value, Rect):
        return value
    if not isinstance(value, list | tuple):
        raise ValueError("a rect is four integers [x, y, w, h]")
    return Rect.from_seq(value)


def _codec(value: Any) -> Codec:
    if isinstance(value, Codec):
        return value
    if not isinstance(value, str):
        raise ValueError("a codec is a name: raw, jpeg or png")
    return Codec.parse(value)


def _state(value: Any) -> SceneState | StateDelta:
    return value if isinstance(value, SceneState | StateDelta) else state_from_json(value)


def _clip(value: Any) -> ClipState:
    return ClipState.from_json(value)


def _counter(value: Any) -> int | float | str:
    if isinstance(value, str) and len(value) <= MAX_COUNTER_TEXT:
        return value
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
        return value
    raise ValueError(f"a counter is a finite number or a text of at most {MAX_COUNTER_TEXT} characters")


Int = StrictInt
Text = StrictStr
Number = StrictFloat
NonNegative = Annotated[StrictFloat, Field(ge=0)]
Unit = Annotated[StrictFloat, Field(ge=0, le=1)]
Jitter = Annotated[StrictFloat, Field(ge=-0.5, lt=0.5)]
Vec3 = tuple[Number, Number, Number]
#: Axis-aligned world-space box: [[x0, y0, z0], [x1, y1, z1]].
Bounds = tuple[Vec3, Vec3]
Side = Annotated[StrictInt, Field(ge=1, le=MAX_SIDE)]
#: Frame size [W, H] in pixels.
Size = tuple[Side, Side]
CameraJson = Annotated[Camera, PlainValidator(_camera), PlainSerializer(Camera.to_json)]
#: Pixel rect [x, y, w, h].
RectJson = Annotated[Rect, PlainValidator(_rect), PlainSerializer(Rect.as_list)]
CodecName = Annotated[Codec, PlainValidator(_codec), PlainSerializer(lambda codec: codec.name.lower())]
Counter = Annotated[int | float | str, PlainValidator(_counter)]
#: A scene state or a delta (:func:`tessera.scene.state.state_from_json`).
StateJson = Annotated[SceneState | StateDelta, PlainValidator(_state), PlainSerializer(lambda state: state.to_json())]
CounterName = Annotated[StrictStr, Field(max_length=MAX_COUNTER_TEXT)]
#: Clip planes and a section box (:class:`tessera.tools.clipping.ClipState`).
ClipJson = Annotated[ClipState, PlainValidator(_clip), PlainSerializer(ClipState.to_json)]
#: A SHA-256 digest: 64 lowercase hex digits.
Sha256 = Annotated[StrictStr, Field(pattern=r"^[0-9a-f]{64}$")]
Url = Annotated[StrictStr, Field(min_length=1, max_length=MAX_URL)]

#: The largest levels-of-detail bound a frame may ask for, in pixels.
MAX_LOD_ERROR_PX = 64.0

_FIELDS = ConfigDict(frozen=True, extra="ignore", allow_inf_nan=False)


class Message(BaseModel):
    """A JSON control message; ``kind`` is its ``type``."""

    model_config = _FIELDS
    kind: ClassVar[str]

    def to_json(self) -> dict[str, Any]:
        return {"type": self.kind, **self.model_dump(mode="json")}

    def _without_none(self, data: dict[str, Any], *keys: str) -> dict[str, Any]:
        """``data`` (the JSON of :meth:`to_json`) without those of ``keys`` whose field is None."""
        for key in keys:
            if getattr(self, key) is None:
                del data[key]
        return data

    def to_text(self) -> str:
        return json.dumps(self.to_json(), separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_json(cls, data: Any) -> Self:
        """Validate a decoded JSON object (its ``type`` is not looked at); raises InvalidMessage."""
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise InvalidMessage(_reason(cls.kind, exc), cls.kind, data) from None


# ------------------------------------------------------------------------------- node → coordinator


class Capabilities(BaseModel):
    """``slowdown``: the node's emulated slowdown factor; ``calibrate``: it answers ``calibrate``;
    ``depth``: it renders depth tiles (``render.depth``) and loads shares (``load_scene.share``),
    which the coordinator's hybrid and sort-last modes need."""

    model_config = _FIELDS
    slowdown: Number = 1.0
    calibrate: StrictBool = False
    depth: StrictBool = False


class NodeHello(Message):
    """A node's first message; a node of another protocol version is refused for that alone.
    ``host``: the machine whose cores it shares (nodes in containers on one host name the same; ""
    from a node that does not say: counted as one machine with every other such node)."""

    kind = "hello"
    name: Text
    token: Text = ""
    renderer: Text = "unknown"
    version: Int
    capabilities: Capabilities = Capabilities()
    host: Annotated[Text, Field(max_length=64)] = ""

    @model_validator(mode="before")
    @classmethod
    def _same_version(cls, data: Any) -> Any:
        version = data.get("version") if isinstance(data, dict) else None
        if version != PROTOCOL_VERSION:
            raise ValueError(f"protocol version {version!r}, coordinator speaks {PROTOCOL_VERSION}")
        return data


class SceneProgress(Message):
    """Loading scene ``scene``: ``fraction`` done (0…1) and what the node is doing (the stage, with
    bytes read or triangles); ``rss_mb``: the node's resident memory now."""

    kind = "scene_progress"
    scene: Text
    fraction: Unit
    message: Text
    rss_mb: NonNegative | None = None

    def to_json(self) -> dict[str, Any]:
        return self._without_none(super().to_json(), "rss_mb")


class SceneGroups(BaseModel):
    """World-space primitive groups (seed 003 DPBP: the octree chunks' boxes, merged to a few
    thousand, at the base pose): ``boxes`` [x0, y0, z0, x1, y1, z1], each one's triangle
    ``counts`` and ``objects``, the index in ``objects`` of scene_ready of the object each belongs
    to (issue 11: the coordinator moves a group with its object; null: groups stay put)."""

    model_config = _FIELDS
    boxes: list[tuple[Number, Number, Number, Number, Number, Number]]
    counts: list[Annotated[StrictInt, Field(ge=0)]]
    objects: list[Annotated[StrictInt, Field(ge=0)]] | None = None

    @model_validator(mode="after")
    def _one_count_per_box(self) -> Self:
        if len(self.boxes) != len(self.counts):
            raise ValueError(f"{len(self.boxes)} boxes but {len(self.counts)} counts")
        if self.objects is not None and len(self.objects) != len(self.boxes):
            raise ValueError(f"{len(self.boxes)} boxes but {len(self.objects)} objects")
        return self


class SceneObjectJson(BaseModel):
    """A named object (:meth:`tessera.scene.graph.ObjectGraph.to_json`): its parent's name (null for
    a root; parents come first), base local transform and visibility, its geometry's world box at
    the base pose (null: none) and triangle count."""

    model_config = _FIELDS
    name: Text
    parent: Text | None = None
    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: tuple[Number, Number, Number, Number] = (0.0, 0.0, 0.0, 1.0)
    scale: Vec3 = (1.0, 1.0, 1.0)
    visible: StrictBool = True
    bounds: Bounds | None = None
    triangles: Annotated[StrictInt, Field(ge=0)] = 0


class AnimationChannelJson(BaseModel):
    """One channel's keyframes (:meth:`tessera.scene.animation.Animation.keyframes_json`)."""

    model_config = _FIELDS
    target: Text
    path: Literal["translation", "rotation", "scale"]
    interpolation: Literal["LINEAR", "STEP", "CUBICSPLINE"]
    times: list[Number]
    values: list[list[Number]]


class AnimationJson(BaseModel):
    model_config = _FIELDS
    name: Text
    channels: list[AnimationChannelJson]


class SceneReady(Message):
    """The scene is loaded: what the coordinator needs of it (the node logs the rest itself). A
    node that lists no ``objects`` renders every frame at the base pose. ``scene``: the spec of the
    ``load_scene`` answered (None: an older node, which holds one scene)."""

    kind = "scene_ready"
    scene: Text | None = None
    triangles: Annotated[StrictInt, Field(ge=0)]
    bounds: Bounds
    groups: SceneGroups | None = None
    objects: list[SceneObjectJson] | None = None
    animations: list[AnimationJson] = Field(default_factory=list)
    #: Sort-last: the data partition version whose share the node loaded (``triangles`` are the
    #: share's, ``bounds`` the whole scene's).
    share: Annotated[StrictInt, Field(ge=1)] | None = None
    #: Issue 31: MB the node holds for this scene (its GPU buffers and what it keeps in memory), MB
    #: of every scene it holds (counted against its ``--scene-memory-mb``), its resident memory.
    scene_mb: NonNegative | None = None
    held_mb: NonNegative | None = None
    rss_mb: NonNegative | None = None
    #: Issue 36: the scene is a point cloud of this many points (its groups count points; None: a mesh).
    points: Annotated[StrictInt, Field(ge=0)] | None = None

    def to_json(self) -> dict[str, Any]:
        """Without ``share`` when the node holds the whole scene, without the other optional fields when None."""
        return self._without_none(super().to_json(), "scene", "share", "scene_mb", "held_mb", "rss_mb", "points")


class SceneError(Message):
    """Scene ``scene`` could not be loaded: the loader's ``message``."""

    kind = "scene_error"
    scene: Text
    message: Text


class TileSent(Message):
    """Sent right after a binary tile: how long sending it took (ms) and the node's per-tile counters."""

    kind = "tile_sent"
    frame: Int
    tile: Int
    send_ms: NonNegative
    stats: dict[CounterName, Counter] = Field(default_factory=dict)
    #: The node's resident memory (MB) when it sent the tile (issue 31); None from older nodes.
    rss_mb: NonNegative | None = None

    def to_json(self) -> dict[str, Any]:
        return self._without_none(super().to_json(), "rss_mb")


class RenderError(Message):
    """A tile the node could not render, with the reason (frame 0, tile 0: a failed calibration)."""

    kind = "render_error"
    frame: Int
    tile: Int
    message: Text


class TilesDropped(Message):
    """Tiles of a cancelled frame the node skipped without rendering them."""

    kind = "tiles_dropped"
    frame: Int
    tiles: tuple[Int, ...]


class LevelsReady(Message):
    """Scene ``scene`` (sort-last: the share of partition ``share``) now has its levels of detail
    (issue 32): ``nodes`` coarse nodes holding ``triangles`` triangles in all. Frames may ask this
    node for a levels-of-detail bound (:attr:`Render.lod_error_px`)."""

    kind = "levels_ready"
    scene: Text
    share: Annotated[StrictInt, Field(ge=1)] | None = None
    nodes: Annotated[StrictInt, Field(ge=0)]
    triangles: Annotated[StrictInt, Field(ge=0)]
    #: For each of ``scene_ready``'s primitive groups and each level (0: full detail … the coarsest):
    #: the level's error over the group (world units), its triangles there and the box [x0, y0, z0,
    #: x1, y1, z1] around them, for the balancers' predictions
    #: (:func:`tessera.balancers.projection.level_counts`); None: not sent.
    group_errors: list[list[NonNegative]] | None = None
    group_triangles: list[list[NonNegative]] | None = None
    group_boxes: list[list[list[Number]]] | None = None

    def to_json(self) -> dict[str, Any]:
        return self._without_none(super().to_json(), "share", "group_errors", "group_triangles", "group_boxes")


class Calibration(Message):
    """The answer to ``calibrate``: the best of its renders of the region, ms (slowdown included)."""

    kind = "calibration"
    ms: Annotated[StrictFloat, Field(gt=0)]


# ------------------------------------------------------------------------------- coordinator → node


class Welcome(Message):
    """The coordinator took the node: its id."""

    kind = "welcome"
    node_id: Int


class ShareSpec(BaseModel):
    """Sort-last (issue 10): keep only share ``index`` of data partition ``version``, the scene's
    chunks split by :func:`tessera.decomposition.data_partition.split_chunks` over ``weights``, one per share
    (the nodes' calibrated speeds)."""

    model_config = _FIELDS
    version: Annotated[StrictInt, Field(ge=1)]
    index: Annotated[StrictInt, Field(ge=0)]
    weights: Annotated[tuple[Annotated[StrictFloat, Field(gt=0)], ...], Field(min_length=1,
                                                                              max_length=MAX_DEPTH_TILES)]

    @model_validator(mode="after")
    def _index_in_range(self) -> Self:
        if self.index >= len(self.weights):
            raise ValueError(f"share {self.index} of {len(self.weights)}")
        return self


class LoadScene(Message):
    """``scene``: ``builtin:NAME`` or a path; ``background``: clear colour, RGB in 0…1; ``share``:
    sort-last, the part of the scene to keep (None: all of it). ``sha256`` (64 lowercase hex
    digits) and ``url``: where a node that cannot open the ``scene`` file itself fetches it, an
    absolute http(s) URL or a path on the coordinator ("/api/scenes/NAME/file"); a ``url`` needs
    its ``sha256``, which the fetched bytes must have. ``levels``: build the scene's levels of
    detail once it is loaded, and say ``levels_ready`` (issue 32; None: the coordinator's frames
    never ask for them)."""

    kind = "load_scene"
    scene: Text
    background: tuple[Unit, Unit, Unit] | None = None
    share: ShareSpec | None = None
    sha256: Sha256 | None = None
    url: Url | None = None
    levels: Literal[True] | None = None

    @model_validator(mode="after")
    def _url_with_digest(self) -> Self:
        if self.url is not None:
            if not self.url.startswith(("http://", "https://", "/")):
                raise ValueError("url must be an http(s) URL or a path on the coordinator starting with /")
            if self.sha256 is None:
                raise ValueError("a url needs the sha256 of the file")
        return self

    def to_json(self) -> dict[str, Any]:
        """Without ``share`` when there is none (the sort-first and hybrid modes), without
        ``sha256``, ``url`` and ``levels`` when None."""
        return self._without_none(super().to_json(), "share", "sha256", "url", "levels")


class RenderTile(BaseModel):
    """Tile ``tile`` of the frame, ``rect``. ``part_of``: the rect of the balancer's tile a display
    wall cut at its cell edges into this piece and others (issue 22); a node draws the pieces of one
    such tile that follow each other in a ``render`` as one rect and sends each piece as its own
    tile (an older node, which ignores the field, draws each piece). None: a whole tile."""

    model_config = _FIELDS
    tile: Int
    rect: RectJson
    part_of: RectJson | None = None

    @model_validator(mode="after")
    def _inside_its_tile(self) -> Self:
        part, rect = self.part_of, self.rect
        if part is not None and not (part.x <= rect.x and rect.x1 <= part.x1 and part.y <= rect.y
                                     and rect.y1 <= part.y1):
            raise ValueError(f"rect {rect.as_list()} is not inside part_of {part.as_list()}")
        return self


class DepthRequest(BaseModel):
    """Render the tiles as depth tiles (issue 10, :mod:`tessera.wire.depth_tiles`). ``mode`` "hybrid"
    (seed 000 §4.4): ``tiles`` is the frame's whole partition (tile ids index it; a node needs
    every tile to find which chunks its tile owns) and ``strip`` the border strip in pixels;
    "sort-last": ``share`` is the data partition version the node's share must be of, and its one
    tile is the whole frame (a render job's: a piece of the picture, drawn in ``window``)."""

    model_config = _FIELDS
    mode: Literal["hybrid", "sort-last"]
    tiles: Annotated[tuple[RectJson, ...], Field(max_length=MAX_DEPTH_TILES)] = ()
    strip: Annotated[StrictInt, Field(ge=0, le=MAX_SIDE)] = 0
    share: Annotated[StrictInt, Field(ge=0)] = 0

    @model_validator(mode="after")
    def _hybrid_has_tiles(self) -> Self:
        if self.mode == "hybrid" and not self.tiles:
            raise ValueError("a hybrid render lists the frame's tiles")
        return self


class Render(Message):
    """Tiles of frame ``frame`` of the scene spec ``scene`` (None: the scene the node loaded last)."""

    kind = "render"
    frame: Int
    camera: CameraJson
    size: Size
    codec: CodecName
    jpeg_quality: Annotated[StrictInt, Field(ge=1, le=100)] = 85
    tiles: tuple[RenderTile, ...]
    state: StateJson | None = None
    depth: DepthRequest | None = None
    scene: Text | None = None
    #: A progressive still's sub-pixel offset (dx, dy) in pixels, x right, y down, each in
    #: [-0.5, 0.5) (:mod:`tessera.scheduling.refinement`); None: the frame is not shifted.
    jitter: tuple[Jitter, Jitter] | None = None
    #: The texture LOD bias of a progressive still's sample (≤ 0); None: no bias.
    lod_bias: Annotated[StrictFloat, Field(ge=-8.0, le=0.0)] | None = None
    #: The session's clip planes and section box (issue 35); None: nothing is cut.
    clip: ClipJson | None = None
    #: The selected object, tinted with its descendants (issue 35); None: none.
    highlight: Text | None = None
    #: The levels of detail's bound for this frame (issue 32): a node draws the coarsest level whose
    #: error is at most this many pixels on screen; None: full detail.
    lod_error_px: Annotated[StrictFloat, Field(gt=0.0, le=MAX_LOD_ERROR_PX)] | None = None
    #: The part of a picture larger than a frame (a poster's, issue 35) whose framebuffer the tiles
    #: are drawn in, the projection narrowed to it; None: the whole frame's.
    window: RectJson | None = None
    #: A point cloud's (issue 36): most points the frame draws (None: all), smallest splat side (px).
    point_budget: Annotated[StrictInt, Field(ge=1)] | None = None
    point_size: Annotated[StrictFloat, Field(gt=0.0, le=MAX_POINT_SIZE)] | None = None
    #: A point cloud's still sample: the spacing on screen its levels are drawn down to (px; 0:
    #: every point in view); None: the node's default (:func:`tessera.points.budget.still_nodes`).
    point_spacing_px: Annotated[StrictFloat, Field(ge=0.0)] | None = None

    def to_json(self) -> dict[str, Any]:
        """Without ``state`` when there is none (a scene whose nodes listed no objects), without
        ``depth`` in sort-first, without ``scene``, ``jitter``, ``lod_bias``, ``clip``,
        ``highlight``, ``lod_error_px``, ``window``, ``point_budget``, ``point_size`` and
        ``point_spacing_px`` when None, without a tile's ``part_of`` when None."""
        data = self._without_none(super().to_json(), "state", "depth", "scene", "jitter", "lod_bias", "clip",
                                  "highlight", "lod_error_px", "window", "point_budget", "point_size",
                                  "point_spacing_px")
        for tile in data["tiles"]:
            if tile["part_of"] is None:
                del tile["part_of"]
        return data


class Calibrate(Message):
    """Time ``rect`` of scene spec ``scene`` (None: the scene the node loaded last), at the levels of
    detail within ``lod_error_px`` pixels (None: full detail), as a moving frame draws it."""

    kind = "calibrate"
    camera: CameraJson
    size: Size
    rect: RectJson
    repeats: Annotated[StrictInt, Field(ge=1, le=MAX_CALIBRATION_REPEATS)] = 3
    scene: Text | None = None
    lod_error_px: Annotated[StrictFloat, Field(gt=0.0, le=MAX_LOD_ERROR_PX)] | None = None

    def to_json(self) -> dict[str, Any]:
        """Without ``scene`` and ``lod_error_px`` when None."""
        return self._without_none(super().to_json(), "scene", "lod_error_px")


class Cancel(Message):
    """These frames were superseded: skip their tiles not begun yet."""

    kind = "cancel"
    frames: tuple[Int, ...]


# ------------------------------------------------------------------------------------------ viewers


class ViewerHello(Message):
    """A viewer's first message: frame size, its id, the newest camera and the scene's bounds (null
    until known), the balancer and those available, the last published frame id, and the samples
    the still frame accumulates (issue 20's progressive still; None: no still frame; with
    ``still_adaptive``, the most it takes: it stops when it converged, issue 37)."""

    kind = "hello"
    size: tuple[Int, Int]
    viewer: Int
    camera: CameraJson | None
    bounds: Bounds | None
    balancer: Text
    balancers: tuple[Text, ...]
    frame: Int
    still_samples: Int | None = None
    still_adaptive: StrictBool = False


class CameraUpdate(Message):
    """The camera moved: from a viewer with its input number ``seq`` (optional), to the other viewers
    without one."""

    kind = "camera"
    camera: CameraJson
    seq: Annotated[StrictInt, Field(ge=0, le=MAX_INPUT_SEQ)] | None = None

    def to_json(self) -> dict[str, Any]:
        return {"type": self.kind, **self.model_dump(mode="json", exclude_none=True)}


class ViewerScene(Message):
    """A node loaded the session's scene: its bounds and the camera framing it."""

    kind = "scene"
    bounds: Bounds
    camera: CameraJson


class ViewerError(Message):
    """The viewer's input was refused: the reason."""

    kind = "error"
    message: Text


class LatencyReport(Message):
    """The viewer's own input → display latency (ms) over its window, and the frame interval."""

    kind = "latency"
    p50_ms: NonNegative
    p90_ms: NonNegative
    samples: NonNegative
    interval_ms: NonNegative


class ViewerSize(Message):
    """The size (w, h px) a session's driving viewer shows frames at: its canvas × devicePixelRatio."""

    kind = "size"
    size: Size


#: What the coordinator accepts from a node after its hello.
FROM_NODE = (SceneProgress, SceneReady, SceneError, LevelsReady, TileSent, TilesDropped, RenderError, Calibration)
#: What a node accepts from the coordinator.
TO_NODE = (Welcome, LoadScene, Render, Calibrate, Cancel)
#: What the coordinator accepts from a viewer.
FROM_VIEWER = (CameraUpdate, LatencyReport, ViewerSize)

M = TypeVar("M", bound=Message)


def parse(text: str | bytes, allowed: Sequence[type[M]]) -> M:
    """Decode a control message of one of the ``allowed`` kinds; raises ProtocolError with the
    reason (InvalidMessage when the object's fields are wrong)."""
    if len(text) > MAX_JSON_BYTES:
        raise ProtocolError(f"control message of {len(text)} bytes exceeds {MAX_JSON_BYTES}")
    try:
        data = json.loads(text, parse_constant=_reject_constant, parse_float=_finite_float)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise ProtocolError(_short(f"malformed JSON: {exc}")) from None
    if not isinstance(data, dict):
        raise ProtocolError("control message must be a JSON object")
    kind = data.get("type")
    for cls in allowed:
        if cls.kind == kind:
            return cls.from_json(data)
    raise ProtocolError(_short(f"unexpected message type {kind!r}; expected one of {[c.kind for c in allowed]}"))


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not allowed")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{_short(text, 40)} overflows to infinity")
    return value


def _reason(kind: str, error: ValidationError) -> str:
    """``kind.field.path: problem`` of the first error (and how many more), at most MAX_REASON long."""
    errors = error.errors(include_url=False, include_input=False)
    first = errors[0]
    where = ".".join(str(part) for part in (kind, *first["loc"]))
    cause = first.get("ctx", {}).get("error")
    problem = str(cause) if first["type"] == "value_error" and cause is not None else first["msg"]
    more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
    return _short(f"{where}: {problem}{more}")


def _short(text: str, limit: int = MAX_REASON) -> str:
    return text if len(text) <= limit else text[:limit - 1] + "…"
