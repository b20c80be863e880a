"""A session as the coordinator serves it (issue 19): one user's picture — its scene, frame size,
camera, scene state and balancer (kept by the scheduler's :class:`SessionFrames`) — with its own
frame store and viewers. The routes act on a session: the default one (made at start-up from
``--scene`` and ``--size``) under ``/api/…``, any other under ``/api/sessions/{id}/…``.

A session's id is the key that drives it (128 random bits, ``secrets.token_urlsafe``); its watch
key is drawn apart, so a watch link (``?session=KEY&watch=1``) cannot be turned into a drive link.
"""

from __future__ import annotations

import contextlib
import secrets
import time
from concurrent.futures import Executor
from typing import Any, Protocol

import numpy as np

from server.frame_store import FrameStore
from server.still_refinement import StillRefiner
from server.viewers import ViewerHub
from tessera.balancers import create_balancer
from tessera.balancers.base import Balancer
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import Camera
from tessera.scene.state import ObjectPatch, SceneStateError
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.scheduler import FrameScheduler
from tessera.scheduling.session_frames import SessionFrames
from tessera.tools.clipping import ClipError, ClipState


class SessionHost(Protocol):
    """What a session needs of the service that holds it."""

    scheduler: FrameScheduler
    #: The thread that accumulates the sessions' progressive stills.
    still_executor: Executor

    @property
    def settings(self) -> Any: ...

    changed_sessions: bool

    def apply(self) -> None:
        """Carry out the scheduler's actions."""

    def fetch_of(self, scene: str) -> tuple[str, str] | None:
        """Where a node fetches scene file ``scene`` (its URL and sha256), if it is a library file."""

    def scene_on_nodes(self, scene: str) -> dict[str, Any]:
        """How the nodes hold scene ``scene``: ``loading`` (its least advanced load: fraction and
        message, and how many nodes hold it of those loading or holding it; None when none loads it)
        and ``scene_mb`` (MB each node holds for it, by node name)."""

#: Random bytes of a session id and of its watch key (128 bits each).
KEY_BYTES = 16
#: Most annotations a session keeps (issue 35).
MAX_ANNOTATIONS = 100


def new_key() -> str:
    return secrets.token_urlsafe(KEY_BYTES)


class Session:
    """Session ``session_id`` of ``service``: ``scene`` is the spec its nodes load (a file path or
    ``builtin:NAME``), ``name`` what the user picked it by (a library name); ``state`` is
    "loading" until a node reported the scene, then "ready", or "error" with ``error``. A display
    wall's session (issue 22) has its ``wall``: its frame is the whole wall, its size fixed."""

    def __init__(self, service: SessionHost, session_id: str, scene: str, name: str | None = None,
                 label: str = "default", wall: WallLayout | None = None) -> None:
        self.service = service
        self.id = session_id
        self.wall = wall
        #: What metrics call it: not its id, which drives it (``/metrics`` is open).
        self.label = label
        self.watch_key = new_key()
        self.scene = scene
        self.name = name or scene
        self.store = FrameStore()
        self.viewers = ViewerHub(wall)
        #: The progressive still's accumulation (issue 20).
        self.refiner = StillRefiner(service.still_executor)
        self.bounds: np.ndarray | None = None
        self.state = "loading"
        self.error: str | None = None
        self.created_at = self.last_used = time.monotonic()
        #: Requests waiting for one of its frames (``GET frame.png``): it is not idle while any waits.
        self.frame_waits = 0
        #: A restored session's object poses and animation clock, applied once its scene is known.
        self.pending_state: dict[str, Any] | None = None
        #: Labels pinned to points of the scene (issue 35): ``{"point": [x, y, z], "text"}`` each.
        self.annotations: list[dict[str, Any]] = []

    @property
    def frames(self) -> SessionFrames:
        """The scheduler's side of the session."""
        return self.service.scheduler.sessions[self.id]

    @property
    def camera(self) -> Camera | None:
        return self.frames.camera

    @property
    def balancer(self) -> Balancer:
        return self.frames.mode.tiles.balancer

    @property
    def size(self) -> tuple[int, int]:
        return self.frames.size

    def touch(self) -> None:
        """Someone used the session now (an API call, a viewer): it is not idle."""
        self.last_used = time.monotonic()

    def idle_for(self, now: float) -> float:
        """Seconds since the session was last used, 0 while a viewer watches it or a request waits
        for one of its frames."""
        return 0.0 if self.viewers.slots or self.frame_waits else now - self.last_used

    # ----------------------------------------------------------------- what users change
    def set_camera(self, camera: Camera, viewer_id: int | None = None, seq: int | None = None) -> int:
        """Make ``camera`` the newest (``seq``: viewer ``viewer_id``'s input number); returns the
        id of the first frame that can show it."""
        return self._event(lambda now: self.service.scheduler.set_camera(camera, now, viewer_id, seq, self.id))

    def set_balancer(self, name: str, params: dict[str, Any]) -> Balancer:
        balancer = create_balancer(name, params)
        self._event(lambda now: self.service.scheduler.set_balancer(balancer, now, self.id))
        return balancer

    def set_objects(self, patches: dict[str, ObjectPatch]) -> int:
        """Pose objects; returns the first frame id that shows it. UnknownObjectError, and nothing
        changes, for a name that is not an object."""
        return self._event(lambda now: self.service.scheduler.set_objects(patches, now, self.id))

    def set_animation(self, playing: bool | None = None, time_s: float | None = None,
                      speed: float | None = None) -> int:
        """Play, pause, jump to ``time_s``, change speed; returns the first frame id that shows it.
        SceneStateError, and nothing changes, for a bad value."""
        return self._event(lambda now: self.service.scheduler.set_animation(now, playing, time_s, speed, self.id))

    def set_clip(self, clip: ClipState | None) -> int:
        """Cut the frames by ``clip``'s planes and box (None or nothing active: no cut) from the
        frame whose id this returns on (issue 35)."""
        clip = clip if clip is not None and clip.active else None

        def change(now: float) -> int:
            self.frames.clip = clip
            return self.service.scheduler.invalidate(now, self.id)

        return self._event(change)

    def select(self, name: str | None) -> int:
        """Draw object ``name`` selected (tinted, with its descendants; None: nothing) from the
        frame whose id this returns on. The caller checks the name is one of the scene's."""

        def change(now: float) -> int:
            self.frames.highlight = name
            return self.service.scheduler.invalidate(now, self.id)

        return self._event(change)

    def resize(self, size: tuple[int, int]) -> int:
        """Frames of ``size`` (w, h) from now on; returns the first frame id of that size."""
        return self._event(lambda now: self.service.scheduler.resize(size, now, self.id))

    @property
    def settled(self) -> bool:
        """At rest and shown: no frame is owed or in flight, no still sample waits to be accumulated,
        and, where stills are on, the newest frame published is the still (``/api/stats``'
        ``settled``; the scheduler's own :attr:`SessionFrames.settled` is true as soon as the last
        sample came back, before the coordinator accumulated and published it)."""
        if not self.frames.settled or self.refiner.pending:
            return False
        latest = self.store.latest
        return self.frames.config.still_codec is None or (latest is not None and latest.still)

    def request_frame(self) -> None:
        """Someone waits for a newer frame: render one if nothing is on its way (render on demand; a
        still's last sample being accumulated is on its way)."""
        if self.frames.settled and not self.refiner.pending:
            self._event(lambda now: self.service.scheduler.invalidate(now, self.id))

    def viewer_left(self, viewer_id: int) -> None:
        frames = self.service.scheduler.sessions.get(self.id)   # None once the session was closed
        if frames is not None:
            frames.forget_source(viewer_id)

    def _event(self, change):
        self.touch()
        result = change(time.monotonic())
        self.service.apply()
        self.service.changed_sessions = True
        return result

    # ----------------------------------------------------------------- across restarts
    def record(self) -> dict[str, Any]:
        """What brings the session back after a restart (plain JSON)."""
        scene, now = self.frames.scene, time.monotonic()
        state = None if scene is None else {
            "poses": {name: patch.to_json() for name, patch in scene.overrides.items()},
            "playing": scene.playing, "time": scene.time_at(now), "speed": scene.speed,
            "selection": self.frames.highlight}
        return {"id": self.id, "watch_key": self.watch_key, "label": self.label, "name": self.name,
                "scene": self.scene, "fetch": self.service.fetch_of(self.scene), "size": list(self.size),
                "camera": self.camera.to_json() if self.camera else None,
                "balancer": {"name": self.balancer.name, "params": self.balancer.params},
                "wall": self.wall.to_json() if self.wall else None,
                "scene_state": state if state is not None else self.pending_state,
                "clip": None if self.frames.clip is None else self.frames.clip.to_json(),
                "annotations": self.annotations}

    def restore_state(self, state: dict[str, Any], now: float) -> None:
        """Object poses and the animation clock of :meth:`record`, once the scene is known; a pose
        of an object the scene no longer has is skipped."""
        scheduler = self.service.scheduler
        for name, pose in dict(state.get("poses") or {}).items():
            try:
                scheduler.set_objects({name: ObjectPatch.from_json(pose, name)}, now, self.id)
            except SceneStateError:
                continue
        with contextlib.suppress(SceneStateError):   # a value the scene no longer takes: its clock as it is
            scheduler.set_animation(now, bool(state.get("playing")), state.get("time"), state.get("speed"), self.id)
        selection = state.get("selection")
        if isinstance(selection, str) and self.frames.scene is not None and selection in self.frames.scene.graph.index:
            self.frames.highlight = selection
            scheduler.invalidate(now, self.id)

    def restore_clip(self, data: Any, annotations: Any = None) -> None:
        """The clip state and annotations of :meth:`record` (a clip that no longer reads is dropped)."""
        with contextlib.suppress(ClipError):
            self.frames.clip = None if data is None else ClipState.from_json(data)
        if isinstance(annotations, list):
            self.annotations = [item for item in annotations[:MAX_ANNOTATIONS] if isinstance(item, dict)]

    # ----------------------------------------------------------------- what users read
    def next_frame_id(self) -> int:
        """The id the next frame to start will have."""
        return self.service.scheduler.next_frame_id

    def scene_timeline(self) -> SceneTimeline | None:
        """The scene's objects, animations and poses (None until a node reported them)."""
        return self.frames.scene

    def scene_state(self) -> dict[str, Any] | None:
        """The newest state version a frame was bound to, the scene time now (s), whether the
        animation plays; None until a node reported the scene's objects."""
        scene = self.frames.scene
        if scene is None:
            return None
        return {"version": scene.log.current.version, "time": scene.time_at(time.monotonic()),
                "playing": scene.playing, "speed": scene.speed, "animated": bool(scene.animations)}

    def summary(self, now: float, public: bool = False) -> dict[str, Any]:
        """The session in ``/api/sessions`` and ``/api/stats``' ``sessions``; ``public``: without its
        id, the key that drives it (for a watcher)."""
        stats = self.frames.stats
        return {**({} if public else {"id": self.id}), "label": self.label, "scene": self.name, "size": list(self.size),
                "viewers": len(self.viewers.slots),
                "fps": round(stats.fps(now), 2), "latency_ms": round(stats.latency_ms, 2),
                "node_share": round(self.service.scheduler.fair.node_share(self.id, now), 4),
                "node_busy_ms": round(self.service.scheduler.fair.busy_ms(self.id, now), 3), "state": self.state,
                "error": self.error, "camera": self.camera.to_json() if self.camera else None,
                "idle_s": round(self.idle_for(now), 1), "wall": self.wall.to_json() if self.wall else None,
                "lod_error_px": self.frames.lod_bound,
                "point_budget": self.frames.point_budget, **self.service.scene_on_nodes(self.scene)}


def fit_size(size: tuple[int, int], largest: tuple[int, int], smallest: int = 16) -> tuple[int, int]:
    """``size`` (w, h) scaled down, aspect kept, to fit inside ``largest``; each side at least
    ``smallest``. ValueError for a side below 1."""
    width, height = size
    if width < 1 or height < 1:
        raise ValueError(f"a frame size is two whole numbers >= 1, got {width}x{height}")
    scale = min(1.0, largest[0] / width, largest[1] / height)
    return max(smallest, min(largest[0], round(width * scale))), max(smallest, min(largest[1], round(height * scale)))
