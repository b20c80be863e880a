"""The coordinator's side of a dynamic scene (issue 11): the objects and animations the nodes
reported, the user's poses, the animation clock, and the :class:`tessera.scene.state.StateLog` of
the states frames were bound to (seed 004: a frame's dynamic data, the same on every node).

Pure: numpy only, no I/O; the clock is read by the caller and passed in as ``now`` (seconds on any
monotonic clock), as the scheduler's events are.

**Scene time.** Paused, the time stays where it was set. Playing, it runs at ``speed`` from where
it was: ``time = time₀ + speed · (now − t₀)``, looped over the animations' span [start, end] (a
negative speed plays backwards), so a scene like ``builtin:traffic`` plays forever.

**A frame's state** is the animations sampled at the frame's scene time, then the user's poses
(:meth:`set_objects`; a pose wins over the animation, as in ``--render-once --objects``), taken
into the log when the frame starts (:meth:`bind`): a new version only when something changed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from tessera.scene.animation import Animation, sample_animations
from tessera.scene.graph import ObjectGraph
from tessera.scene.state import OBJECT_FIELDS, ObjectPatch, SceneState, SceneStateError, StateLog

#: Largest |speed| accepted: faster than this the frames show unrelated instants.
MAX_SPEED = 1000.0


def merged(old: ObjectPatch | None, new: ObjectPatch) -> ObjectPatch:
    """``old`` with the fields ``new`` sets replaced."""
    if old is None:
        return new
    return ObjectPatch(*(getattr(new, key) if getattr(new, key) is not None else getattr(old, key)
                         for key in OBJECT_FIELDS))


def _finite(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SceneStateError(f"{what} must be a finite number, got {value!r}")
    return float(value)


class SceneTimeline:
    """The scene's objects (``graph``), ``animations``, the user's poses (``overrides``), the clock
    (``playing``, ``speed``) and the ``log`` of bound states. Starts paused at the animations' start."""

    def __init__(self, graph: ObjectGraph, animations: Sequence[Animation] = (), now: float = 0.0) -> None:
        for animation in animations:
            for channel in animation.channels:
                graph.lookup(channel.target)
        self.graph = graph
        self.animations = tuple(animations)
        self.start = min((a.start for a in self.animations), default=0.0)
        self.end = max((a.end for a in self.animations), default=0.0)
        self.overrides: dict[str, ObjectPatch] = {}
        self.playing = False
        self.speed = 1.0
        self._time, self._since = self.start, now
        self.log = StateLog(self.state_at(now))

    @property
    def animating(self) -> bool:
        """The state changes by itself: playing, at a non-zero speed, over a span of time."""
        return self.playing and self.speed != 0.0 and self.end > self.start

    def time_at(self, now: float) -> float:
        """The scene time (s) at clock reading ``now``."""
        if not self.playing:
            return self._time
        time = self._time + self.speed * (now - self._since)
        span = self.end - self.start
        return self.start + (time - self.start) % span if span > 0.0 else time

    def state_at(self, now: float) -> SceneState:
        """The state at ``now`` (not logged: version 0)."""
        time = self.time_at(now)
        return self.graph.posed(time, sample_animations(self.animations, time), self.overrides)

    def bind(self, now: float) -> SceneState:
        """The state at ``now`` as the log's current version (the same version when nothing changed):
        what a frame starting now shows."""
        state = self.state_at(now)
        return self.log.update(dict(state.objects), state.time)

    def set_objects(self, patches: Mapping[str, ObjectPatch]) -> None:
        """Pose objects (each patch merged into the object's earlier pose). Raises UnknownObjectError
        for a name that is not an object, and then nothing changes."""
        for name in patches:
            self.graph.lookup(name)
        for name, patch in patches.items():
            self.overrides[name] = merged(self.overrides.get(name), patch)

    def set_animation(self, now: float, playing: bool | None = None, time: float | None = None,
                      speed: float | None = None) -> None:
        """Play or pause, jump to ``time`` (s), change ``speed``; what is None stays. Raises
        SceneStateError for a bad value, and then nothing changes."""
        if playing is not None and not isinstance(playing, bool):
            raise SceneStateError(f"playing must be true or false, got {playing!r}")
        new_time = self.time_at(now) if time is None else _finite(time, "time")
        new_speed = self.speed if speed is None else _finite(speed, "speed")
        if abs(new_speed) > MAX_SPEED:
            raise SceneStateError(f"speed must be within ±{MAX_SPEED:g}, got {new_speed!r}")
        self._time, self._since, self.speed = new_time, now, new_speed
        if playing is not None:
            self.playing = playing

    def animation_json(self, now: float) -> dict[str, Any]:
        """``{"playing", "time", "speed", "start", "end", "animations": [{name, start, end, targets}]}``."""
        return {"playing": self.playing, "time": self.time_at(now), "speed": self.speed, "start": self.start,
                "end": self.end, "animations": [a.to_json() for a in self.animations]}

    def objects_json(self, now: float) -> list[dict[str, Any]]:
        """Every object at ``now``: name, parent, its local transform and visibility, its world
        ``bounds`` where it is now (null without geometry) and its triangles."""
        state = self.state_at(now)
        out = self.graph.to_json(state)
        for entry, box in zip(out, self.graph.world_bounds(state), strict=True):
            entry["bounds"] = None if box is None else box.tolist()
        return out
