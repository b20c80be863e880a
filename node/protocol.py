"""The render node's side of the coordinator conversation, without I/O (the sans-I/O pattern of
websockets' ``Protocol``): :class:`NodeProtocol` takes the coordinator's text messages and the
results of the node's work in, and hands actions out — load this scene, draw this tile of this
frame in this state, calibrate, send this message — for :class:`node.client.NodeClient` to carry
out with the GL thread, the encoder and the socket. No sockets, no GL, no asyncio, no clocks.

Messages follow the catalogue in :mod:`tessera.wire.messages`. Cancels and the welcome take effect
at once on receipt; everything else is a job, done in order:

- ``load_scene``: of several waiting, only the newest is loaded (the others are superseded);
- ``render``: its state brings the node's :class:`tessera.scene.state.StateReplica` to the frame's
  scene state (issue 11), in message order, also for a frame cancelled since (a state that does
  not apply fails all its tiles); then its tiles are handed out one at a time, each once the one
  before is done, so a ``cancel`` received meanwhile drops the tiles not begun, reported together
  in a ``tiles_dropped`` after the frame's last tile;
- ``calibrate``;
- a message that names one of these kinds but is malformed is refused in its turn, as far as it
  can be read: a ``render``'s tiles fail with ``render_error``, a ``calibrate`` fails, a
  ``load_scene`` is a ``scene_error``.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from node.scene.data import SceneData
from tessera.scene.state import SceneState, SceneStateError, StateReplica
from tessera.wire import messages
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError

log = logging.getLogger("tessera.node")

#: Cancelled frame ids a node remembers (its queue never holds more frames than this).
CANCELLED_MEMORY = 256

#: The node's work, done in order: coordinator messages, and malformed ones to refuse.
Job = messages.LoadScene | messages.Render | messages.Calibrate | messages.InvalidMessage


@dataclass(frozen=True, slots=True)
class Load:
    """Load (or reuse) the scene ``request`` names; then report :meth:`NodeProtocol.scene_loaded`
    or :meth:`NodeProtocol.scene_failed`."""

    request: messages.LoadScene


@dataclass(frozen=True, slots=True)
class Draw:
    """Draw ``tile`` of the frame ``render`` asks for (a depth tile when it has a depth request) in
    scene ``state`` (None: the base pose); report a failure with :meth:`NodeProtocol.tile_failed`."""

    render: messages.Render
    tile: messages.RenderTile
    state: SceneState | None


@dataclass(frozen=True, slots=True)
class Measure:
    """Time the region ``request`` asks for (a calibration); report a failure with
    :meth:`NodeProtocol.calibration_failed`."""

    request: messages.Calibrate


@dataclass(frozen=True, slots=True)
class Send:
    """Send ``message`` to the coordinator, after what is already on its way."""

    message: messages.Message


NodeAction = Load | Draw | Measure | Send


@dataclass
class _FrameTiles:
    """A ``render`` job whose tiles are being handed out: those still to come, those dropped."""

    render: messages.Render
    state: SceneState | None
    tiles: Iterator[messages.RenderTile]
    dropped: list[int] = field(default_factory=list)


class NodeProtocol:
    """One node's protocol state across its connections: ``name``, ``token`` and the emulated
    ``slowdown`` it says hello with; :attr:`node_id` and :attr:`welcomed` from the coordinator's
    welcome; :attr:`tiles_dropped` counts tiles skipped for a cancelled frame.

    Per connection: :meth:`connect`, then :meth:`receive_text` for each text message and
    :meth:`next_action` until it gives None (more comes with the next message); the results of
    the work it hands out go back through :meth:`scene_loaded`, :meth:`scene_failed`,
    :meth:`tile_failed`, :meth:`encoding_failed` and :meth:`calibration_failed`, which give the
    message to send. The cancel memory outlives a connection; the scene state does not.
    """

    def __init__(self, name: str, token: str = "", slowdown: float = 1.0) -> None:
        self.name, self.token, self.slowdown = name, token, slowdown
        self.node_id: int | None = None
        self.welcomed = False
        self.tiles_dropped = 0
        self._cancelled: deque[int] = deque(maxlen=CANCELLED_MEMORY)
        self._replica = StateReplica()
        self._jobs: deque[Job] = deque()
        self._newest_load: messages.LoadScene | None = None
        self._ready: deque[NodeAction] = deque()
        self._frame: _FrameTiles | None = None

    def connect(self, renderer: str) -> messages.NodeHello:
        """A new connection (attempt) of the node whose GL renderer is ``renderer``: not welcomed
        yet, no scene state, no work waiting; returns the hello to send first."""
        self.welcomed = False
        self._replica = StateReplica()
        self._jobs.clear()
        self._ready.clear()
        self._frame = None
        self._newest_load = None
        capabilities = messages.Capabilities(slowdown=self.slowdown, calibrate=True, depth=True)
        return messages.NodeHello(name=self.name, token=self.token, renderer=renderer, version=PROTOCOL_VERSION,
                                  capabilities=capabilities)

    def receive_text(self, text: str) -> None:
        """Take a text message: a cancel or the welcome takes effect now, other kinds wait as jobs
        (a malformed one too, refused in its turn); anything else is logged and ignored."""
        try:
            message = messages.parse(text, messages.TO_NODE)
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
                self._newest_load = message
                self._jobs.append(message)
            case messages.Render() | messages.Calibrate():
                self._jobs.append(message)

    def next_action(self) -> NodeAction | None:
        """What to do next, in order; None: nothing waits. Ask again once an action is done (a
        tile of a cancelled frame is dropped when its turn comes)."""
        while True:
            if self._ready:
                return self._ready.popleft()
            if self._frame is not None:
                self._next_tile(self._frame)
            elif self._jobs:
                self._start(self._jobs.popleft())
            else:
                return None

    def _start(self, job: Job) -> None:
        match job:
            case messages.LoadScene():
                if job is self._newest_load:   # else a newer one waits: this one is superseded
                    self._ready.append(Load(job))
            case messages.Calibrate():
                self._ready.append(Measure(job))
            case messages.Render():
                self._start_frame(job)
            case messages.InvalidMessage():
                self._refuse(job)

    def _start_frame(self, render: messages.Render) -> None:
        """Bring the replica to ``render``'s state (in message order, cancelled or not), then hand
        out its tiles; a state that does not apply fails them all."""
        try:
            state = None if render.state is None else self._replica.receive(render.state)
        except SceneStateError as exc:
            self._fail_tiles(render.frame, [t.tile for t in render.tiles], f"scene state: {exc}")
            return
        self._frame = _FrameTiles(render, state, iter(render.tiles))

    def _next_tile(self, frame: _FrameTiles) -> None:
        """Hand out ``frame``'s next tile unless its frame is cancelled; after the last, the dropped."""
        render = frame.render
        for tile in frame.tiles:
            if render.frame not in self._cancelled:
                self._ready.append(Draw(render, tile, frame.state))
                return
            frame.dropped.append(tile.tile)
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

    def _fail_tiles(self, frame: int, tiles: list[int], reason: str) -> None:
        self._ready.extend(Send(messages.RenderError(frame=frame, tile=tile, message=reason)) for tile in tiles)

    @staticmethod
    def scene_loaded(scene: SceneData, share: int | None) -> messages.SceneReady:
        """The ``scene_ready`` of ``scene``, loaded (sort-last: the share of partition ``share``)."""
        groups = messages.SceneGroups(boxes=scene.groups.boxes.tolist(), counts=scene.groups.counts.tolist(),
                                      objects=scene.groups.owners.tolist())
        return messages.SceneReady(triangles=scene.triangle_count, bounds=scene.bounds.tolist(), groups=groups,
                                   objects=scene.objects.to_json(),
                                   animations=[a.keyframes_json() for a in scene.animations], share=share)

    @staticmethod
    def scene_failed(spec: str, error: Exception) -> messages.SceneError:
        """The ``scene_error`` of scene ``spec``, whose loading raised ``error``."""
        reason = one_line(error) or type(error).__name__
        log.warning("scene %s failed: %s", spec, reason)
        return messages.SceneError(scene=spec, message=reason)

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


def one_line(error: Exception) -> str:
    """``error``'s message with its whitespace runs as single spaces."""
    return " ".join(str(error).split())


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
