"""The render node's side of the coordinator conversation, without I/O (the sans-I/O pattern of
websockets' ``Protocol``): :class:`NodeProtocol` takes the coordinator's text messages and the
results of the node's work in, and hands actions out — load this scene, draw this tile of this
scene and frame in this state, calibrate, send this message — for :class:`node.client.NodeClient`
to carry out with the GL thread, the encoder and the socket. No sockets, no GL, no asyncio, no
clocks.

Messages follow the catalogue in :mod:`tessera.wire.messages`. Cancels and the welcome take effect
at once on receipt; a ``render``'s state brings the node's :class:`tessera.scene.state.StateReplica`
to the frame's scene state (issue 11) on receipt too, so in message order, also for a frame
cancelled since (a state that does not apply fails all its tiles in the frame's turn). A node
holds several scenes (issue 19), so the rest is:

- ``load_scene``: a background action, handed out at once: the scene is read while tiles of the
  scenes already held are drawn, and its end comes back as :meth:`NodeProtocol.scene_loaded` or
  :meth:`NodeProtocol.scene_failed`. One load per key (scene and share) runs at a time; of several
  waiting for the same key, only the newest is loaded (the others are superseded);
- ``render`` and ``calibrate``: jobs, done in message order, each of the scene it names (None: the
  scene of the newest ``load_scene`` received, else whatever the node loaded last). A job waits
  while a load of its scene received before it is under way, and later jobs pass it by, except
  those of the same scene; a load that fails fails the jobs waiting for it with the reason. A
  ``render``'s tiles are handed out one at a time (the pieces of a display wall's tile together,
  drawn as one: :class:`Draw`), each once the one before is done, so a
  ``cancel`` received meanwhile drops the tiles not begun, reported together in a
  ``tiles_dropped`` after the frame's last tile (a cancelled frame waits for no load); a tile
  being drawn may be given up for it too (a point cloud's, between two pieces:
  :meth:`NodeProtocol.cancelled`, :meth:`NodeProtocol.draw_stopped`);
- ``pick`` (issue 35): handed out before the jobs waiting (after the tile being drawn), its state
  whole and not applied to the replica (the renders' deltas stay based on what they were);
- a message that names one of these kinds but is malformed is refused in its turn, as far as it
  can be read: a ``render``'s tiles fail with ``render_error``, a ``calibrate`` fails, a
  ``load_scene`` is a ``scene_error``, a ``pick`` is answered with its error.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from node.scene.data import SceneData
from node.scene.points import PointCloud
from tessera.geometry import Rect
from tessera.scene.state import SceneState, SceneStateError, StateReplica
from tessera.wire import messages
from tessera.wire.pick_messages import TO_NODE_PICKS, Pick, PickResult
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError

log = logging.getLogger("tessera.node")

#: Cancelled frame ids a node remembers.
CANCELLED_MEMORY = 256

#: A load's key: its scene spec and share (index, weights; None: the whole scene).
LoadKey = tuple[str, tuple[int, tuple[float, ...]] | None]


@dataclass(frozen=True, slots=True)
class Load:
    """Load (or reuse) the scene ``request`` names, in the background; then report
    :meth:`NodeProtocol.scene_loaded` or :meth:`NodeProtocol.scene_failed` with it."""

    request: messages.LoadScene


@dataclass(frozen=True, slots=True)
class Draw:
    """Draw ``tile`` of the frame ``render`` asks for (a depth tile when it has a depth request) of
    ``scene`` (a spec; None: the scene loaded last) in scene ``state`` (None: the base pose);
    report a failure with :meth:`NodeProtocol.tile_failed`. ``pieces``: the tiles of the render
    cut from a display wall's tile (``part_of``), which ``tile`` then covers exactly: drawn once as
    ``tile`` (its id the first piece's), each piece sent as its own tile; empty: ``tile`` is sent."""

    render: messages.Render
    tile: messages.RenderTile
    state: SceneState | None
    scene: str | None = None
    pieces: tuple[messages.RenderTile, ...] = ()

    @property
    def sent(self) -> tuple[messages.RenderTile, ...]:
        """The tiles this draw sends (or fails) in order."""
        return self.pieces or (self.tile,)


@dataclass(frozen=True, slots=True)
class Measure:
    """Time the region ``request`` asks for (a calibration) of ``scene`` (None: the scene loaded
    last); report a failure with :meth:`NodeProtocol.calibration_failed`."""

    request: messages.Calibrate
    scene: str | None = None


@dataclass(frozen=True, slots=True)
class PickPixel:
    """Answer ``request``: draw the id pass of its pixel and send a ``pick_result``."""

    request: Pick


@dataclass(frozen=True, slots=True)
class Send:
    """Send ``message`` to the coordinator, after what is already on its way."""

    message: messages.Message


NodeAction = Load | Draw | Measure | PickPixel | Send


def load_key(request: messages.LoadScene) -> LoadKey:
    """The scene and share ``request`` loads: two loads of one key hold the same data."""
    share = request.share
    return request.scene, None if share is None else (share.index, share.weights)


@dataclass(eq=False)
class _PendingLoad:
    """A ``load_scene`` waiting or under way; ``first``: the number of the oldest ``load_scene`` it
    answers (it supersedes those of its key that waited before it)."""

    request: messages.LoadScene
    first: int


@dataclass(eq=False)
class _SceneJob:
    """A ``render`` or ``calibrate`` of ``scene`` (None: the scene loaded last), received after
    ``load_scene`` number ``after``; a render's ``state``, or why its state does not apply."""

    message: messages.Render | messages.Calibrate
    scene: str | None
    after: int
    state: SceneState | None = None
    state_error: str | None = None


#: The node's jobs, in message order: renders and calibrations, and malformed messages to refuse.
Job = _SceneJob | messages.InvalidMessage


@dataclass
class _FrameTiles:
    """A ``render`` job whose tiles are being handed out: those still to come, those dropped."""

    job: _SceneJob
    render: messages.Render
    tiles: deque[messages.RenderTile]
    dropped: list[int] = field(default_factory=list)


class NodeProtocol:
    """One node's protocol state across its connections: ``name``, ``token``, the emulated
    ``slowdown`` and the ``host`` it says hello with; :attr:`node_id` and :attr:`welcomed` from the coordinator's
    welcome; :attr:`tiles_dropped` counts tiles skipped for a cancelled frame.

    Per connection: :meth:`connect`, then :meth:`receive_text` for each text message and
    :meth:`next_action` until it gives None (more comes with the next message or the end of a
    load); the results of the work it hands out go back through :meth:`scene_loaded`,
    :meth:`scene_failed`, :meth:`tile_failed`, :meth:`draw_stopped`, :meth:`encoding_failed` and
    :meth:`calibration_failed`, which give the message to send. Nothing of a connection outlives
    it: not the cancel memory (a restarted coordinator numbers its frames from the start again),
    the scene state or the loads waiting or under way.
    """

    def __init__(self, name: str, token: str = "", slowdown: float = 1.0, host: str = "") -> None:
        self.name, self.token, self.slowdown, self.host = name, token, slowdown, host
        self.node_id: int | None = None
        self.welcomed = False
        self.tiles_dropped = 0
        self._cancelled: deque[int] = deque(maxlen=CANCELLED_MEMORY)
        self._replica = StateReplica()
        self._jobs: deque[Job] = deque()
        self._picks: deque[Pick] = deque()
        self._ready: deque[NodeAction] = deque()
        self._frame: _FrameTiles | None = None
        self._load_count = 0
        self._newest_scene: str | None = None
        self._waiting: dict[LoadKey, _PendingLoad] = {}
        self._running: dict[LoadKey, _PendingLoad] = {}

    def connect(self, renderer: str) -> messages.NodeHello:
        """A new connection (attempt) of the node whose GL renderer is ``renderer``: not welcomed
        yet, no cancelled frames, no scene state, no work waiting (loads under way are forgotten);
        returns the hello to send first."""
        self.welcomed = False
        self._cancelled.clear()
        self._replica = StateReplica()
        self._jobs.clear()
        self._picks.clear()
        self._ready.clear()
        self._frame = None
        self._newest_scene = None
        self._waiting.clear()
        self._running.clear()
        capabilities = messages.Capabilities(slowdown=self.slowdown, calibrate=True, depth=True)
        return messages.NodeHello(name=self.name, token=self.token, renderer=renderer, version=PROTOCOL_VERSION,
                                  capabilities=capabilities, host=self.host)

    def receive_text(self, text: str) -> None:
        """Take a text message: a cancel or the welcome takes effect now, a load waits to be handed
        out, other kinds wait as jobs (a malformed one too, refused in its turn); anything else is
        logged and ignored."""
        try:
            message = messages.parse(text, (*messages.TO_NODE, *TO_NODE_PICKS))
        except messages.InvalidMessage as exc:
            self._jobs.append(exc)
            return
        except ProtocolError as exc:
            log.warning("ignoring coordinator message: %s", exc)
            return
        match message:
            case messages.Cancel():
                self._cancelled.extend(message.frames)
            case messages.Welcome():
                self.node_id = message.node_id
                self.welcomed = True
                log.info("registered as node %s", self.node_id)
            case messages.LoadScene():
                self._receive_load(message)
            case messages.Render() | messages.Calibrate():
                self._jobs.append(self._scene_job(message))
            case Pick():
                self._picks.append(message)

    def _receive_load(self, request: messages.LoadScene) -> None:
        """Queue ``request``'s load; one of its key waiting already is superseded by it."""
        self._load_count += 1
        self._newest_scene = request.scene
        key = load_key(request)
        superseded = self._waiting.pop(key, None)
        self._waiting[key] = _PendingLoad(request, self._load_count if superseded is None else superseded.first)

    def _scene_job(self, message: messages.Render | messages.Calibrate) -> _SceneJob:
        """``message`` as a job of its scene, after the loads received so far; a render's state
        applied now, in message order."""
        job = _SceneJob(message, message.scene or self._newest_scene, self._load_count)
        if isinstance(message, messages.Render) and message.state is not None:
            try:
                job.state = self._replica.receive(message.state)
            except SceneStateError as exc:
                job.state_error = f"scene state: {exc}"
        return job

    def next_action(self) -> NodeAction | None:
        """What to do next: loads first (they run in the background), then the jobs in order, a job
        waiting for its scene's load passed by; None: nothing can be done now. Ask again once an
        action is done or a load ended (a tile of a cancelled frame is dropped when its turn comes)."""
        while True:
            if self._ready:
                return self._ready.popleft()
            if (load := self.next_load()) is not None:
                return load
            if self._picks:
                return PickPixel(self._picks.popleft())
            if self._frame is not None:
                self._next_tile(self._frame)
                continue
            job = next((job for job in self._jobs if not self._waits(job)), None)
            if job is None:
                return None
            self._jobs.remove(job)
            self._start(job)

    def next_load(self) -> Load | None:
        """A load waiting to be handed out (None: none), also while a tile is being drawn: loads run
        in the background, so a scene received meanwhile (a mesh step loaded ahead) is read while
        the tile of the scene shown is drawn, not after it."""
        load = next((key for key in self._waiting if key not in self._running), None)
        if load is None:
            return None
        pending = self._running[load] = self._waiting.pop(load)
        return Load(pending.request)

    def _waits(self, job: Job) -> bool:
        """Whether ``job`` waits for a load of its scene received before it (a cancelled frame does not)."""
        if not isinstance(job, _SceneJob) or job.scene is None:
            return False
        if isinstance(job.message, messages.Render) and job.message.frame in self._cancelled:
            return False
        return any(self._holds_back(pending, job) for pending in (*self._running.values(), *self._waiting.values()))

    @staticmethod
    def _holds_back(pending: _PendingLoad, job: _SceneJob) -> bool:
        return pending.request.scene == job.scene and pending.first <= job.after

    def _start(self, job: Job) -> None:
        match job:
            case messages.InvalidMessage():
                self._refuse(job)
            case _SceneJob(message=messages.Calibrate() as calibrate):
                self._ready.append(Measure(calibrate, job.scene))
            case _SceneJob(message=messages.Render() as render):
                if job.state_error is not None:
                    self._fail_tiles(render.frame, [t.tile for t in render.tiles], job.state_error)
                else:
                    self._frame = _FrameTiles(job, render, deque(render.tiles))

    def _next_tile(self, frame: _FrameTiles) -> None:
        """Hand out ``frame``'s next tile (or a wall tile's pieces, together) unless its frame is
        cancelled; after the last, the dropped."""
        render = frame.render
        while frame.tiles:
            draw = _next_draw(frame.tiles, render, frame.job)
            if render.frame not in self._cancelled:
                self._ready.append(draw)
                return
            frame.dropped.extend(tile.tile for tile in draw.sent)
        self._frame = None
        if frame.dropped:
            self.tiles_dropped += len(frame.dropped)
            log.debug("frame %d superseded: %d queued tiles dropped", render.frame, len(frame.dropped))
            self._ready.append(Send(messages.TilesDropped(frame=render.frame, tiles=tuple(frame.dropped))))

    def _refuse(self, error: messages.InvalidMessage) -> None:
        """Answer a malformed message as far as it can be read: a ``render``'s tiles fail, a
        ``calibrate`` fails, a ``load_scene`` is a scene error."""
        log.warning("bad coordinator message: %s", error)
        data, reason = error.data, str(error)
        if error.kind == messages.Render.kind:
            frame, tiles = data.get("frame"), data.get("tiles")
            if _is_int(frame) and isinstance(tiles, list):
                self._fail_tiles(frame, [t["tile"] for t in tiles if isinstance(t, dict) and _is_int(t.get("tile"))],
                                 reason)
        elif error.kind == messages.Calibrate.kind:
            self._ready.append(Send(messages.RenderError(frame=0, tile=0, message=f"calibration failed: {reason}")))
        elif error.kind == messages.LoadScene.kind:
            self._ready.append(Send(messages.SceneError(scene=str(data.get("scene")), message=reason)))
        elif error.kind == Pick.kind and _is_int(data.get("id")) and data["id"] >= 0:
            self._ready.append(Send(PickResult(id=data["id"], hit=False, error=reason)))

    def _fail_tiles(self, frame: int, tiles: list[int], reason: str) -> None:
        self._ready.extend(Send(messages.RenderError(frame=frame, tile=tile, message=reason)) for tile in tiles)

    def _finished(self, request: messages.LoadScene) -> _PendingLoad | None:
        """The load of ``request`` ended: no longer under way (None: not one of this connection's)."""
        key = load_key(request)
        pending = self._running.get(key)
        if pending is None or pending.request is not request:
            return None
        return self._running.pop(key)

    def scene_loaded(self, request: messages.LoadScene, scene: SceneData | PointCloud,
                     share: int | None) -> messages.SceneReady:
        """The load of ``request`` ended with ``scene`` held (sort-last: the share of partition
        ``share``): the jobs waiting for it may go; returns its ``scene_ready``."""
        self._finished(request)
        groups = messages.SceneGroups(boxes=scene.groups.boxes.tolist(), counts=scene.groups.counts.tolist(),
                                      objects=scene.groups.owners.tolist())
        return messages.SceneReady(scene=request.scene, triangles=scene.triangle_count, bounds=scene.bounds.tolist(),
                                   groups=groups, objects=scene.objects.to_json(),
                                   animations=[a.keyframes_json() for a in scene.animations], share=share,
                                   points=scene.point_count if isinstance(scene, PointCloud) else None)

    def scene_failed(self, request: messages.LoadScene, error: Exception) -> messages.SceneError:
        """The load of ``request`` raised ``error``: the jobs waiting for it fail with the reason
        (their messages are handed out next); returns its ``scene_error``."""
        reason = one_line(error) or type(error).__name__
        log.warning("scene %s failed: %s", request.scene, reason)
        pending = self._finished(request)
        if pending is not None:
            failed = [job for job in self._jobs if isinstance(job, _SceneJob) and self._holds_back(pending, job)]
            for job in failed:
                self._jobs.remove(job)
                self._fail_job(job, f"scene {request.scene} failed to load: {reason}")
        return messages.SceneError(scene=request.scene, message=reason)

    def _fail_job(self, job: _SceneJob, reason: str) -> None:
        if isinstance(job.message, messages.Render):
            self._fail_tiles(job.message.frame, [t.tile for t in job.message.tiles], reason)
        else:
            self._ready.append(Send(messages.RenderError(frame=0, tile=0, message=f"calibration failed: {reason}")))

    def cancelled(self, frame: int) -> bool:
        """Whether frame ``frame`` was cancelled: a tile of it being drawn may be given up."""
        return frame in self._cancelled

    def draw_stopped(self, frame: int, tiles: list[int]) -> messages.TilesDropped:
        """The ``tiles_dropped`` of ``tiles`` of the cancelled ``frame``, whose draw was given up."""
        self.tiles_dropped += len(tiles)
        return messages.TilesDropped(frame=frame, tiles=tuple(tiles))

    @staticmethod
    def tile_failed(frame: int, tile: int, error: Exception) -> messages.RenderError:
        """The ``render_error`` of a tile whose drawing raised ``error`` (the node keeps serving)."""
        return messages.RenderError(frame=frame, tile=tile, message=one_line(error))

    @staticmethod
    def encoding_failed(frame: int, tile: int, error: Exception) -> messages.RenderError:
        """The ``render_error`` of a drawn tile whose encoding raised ``error``."""
        return messages.RenderError(frame=frame, tile=tile, message=f"encoding failed: {error}")

    @staticmethod
    def calibration_failed(error: Exception) -> messages.RenderError:
        """The ``render_error`` of a calibration whose renders raised ``error``."""
        log.warning("calibration failed: %s", error)
        return messages.RenderError(frame=0, tile=0, message=f"calibration failed: {one_line(error)}")


def _next_draw(tiles: deque[messages.RenderTile], render: messages.Render, job: _SceneJob) -> Draw:
    """The next draw of ``tiles`` (taken from them): the next tile, with the pieces of its wall tile
    that follow it when they cover one rect exactly (a plain render's only: depth tiles are drawn
    each as its own)."""
    first = tiles.popleft()
    part = first.part_of
    pieces = [first]
    while part is not None and render.depth is None and tiles and tiles[0].part_of == part:
        pieces.append(tiles.popleft())
    rects = [piece.rect for piece in pieces]
    x0, y0 = min(r.x for r in rects), min(r.y for r in rects)
    drawn = Rect(x0, y0, max(r.x1 for r in rects) - x0, max(r.y1 for r in rects) - y0)
    if len(pieces) > 1 and sum(r.area for r in rects) == drawn.area:
        return Draw(render, messages.RenderTile(tile=first.tile, rect=drawn), job.state, job.scene, tuple(pieces))
    tiles.extendleft(reversed(pieces[1:]))
    return Draw(render, first, job.state, job.scene)


def one_line(error: Exception) -> str:
    """``error``'s message with its whitespace runs as single spaces."""
    return " ".join(str(error).split())


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
