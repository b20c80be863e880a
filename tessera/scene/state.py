"""A frame's scene state (issue 11; seed 004's cluster model, where each render host's CULL stage
waits for the frame's dynamic data — camera, object transforms — so that every tile of a frame
shows the same instant; seed 000 lists dynamic scenes among a partition's goals).

Pure: numpy only, no GL, no I/O. The camera travels on its own (:mod:`tessera.geometry`); this
module holds the rest of a frame's state:

* :class:`ObjectState` — one object's *local* transform (relative to its parent, glTF's node
  TRS: ``translation`` [x, y, z] in scene units, ``rotation`` a unit quaternion [qx, qy, qz, qw],
  ``scale`` [sx, sy, sz]) and whether it is ``visible``. Its matrix is T·R·S (glTF 2.0 §3.5.3).
  :class:`ObjectPatch` is any subset of those fields (what ``PUT /api/objects/{name}``, a
  ``--objects`` file and an animation channel give).
* :class:`SceneState` — scene time (seconds) and every object's state, with a version: version
  K + 1 is version K with some objects changed. :class:`StateDelta` carries those changes from a
  base version to another (either direction: it lists the objects that differ), so a render
  message carries a version plus a small delta, and a node that has nothing yet (it joined
  mid-animation) gets the full state instead.
* :class:`StateLog` — the coordinator's side: the current state, recent versions, and for a node
  that last got version J the cheapest payload that brings it to the current version.

Validation (:class:`SceneStateError`, one line naming the object and field): numbers must be finite,
a rotation must have a non-zero length (it is normalised), a scale component must be finite and
not zero. Negative scales are accepted: glTF allows mirroring nodes, and a mirrored node's matrix
decomposes into one (:meth:`ObjectState.from_matrix`).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np

#: Smallest |scale| component accepted: below it the matrix is too close to singular to invert.
MIN_SCALE = 1e-9
#: A rotation whose length is this close to 1 is taken as unit and kept bit for bit.
UNIT_TOLERANCE = 1e-12
#: Recent versions a :class:`StateLog` keeps for deltas; older ones get the full state.
HISTORY = 64
OBJECT_FIELDS = ("translation", "rotation", "scale", "visible")

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


class SceneStateError(ValueError):
    """A state, patch or delta that cannot be used: bad numbers, unknown objects, wrong base."""


class UnknownObjectError(SceneStateError, KeyError):
    """A name that is not one of the scene's objects."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def _numbers(value: Any, count: int, where: str) -> tuple[float, ...]:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, list | tuple) or len(value) != count:
        raise SceneStateError(f"{where} must be a list of {count} numbers, got {_short(value)}")
    out = []
    for item in value:
        if isinstance(item, bool) or not isinstance(item, int | float | np.integer | np.floating):
            raise SceneStateError(f"{where} must be numbers, got {_short(value)}")
        number = float(item)
        if not math.isfinite(number):
            raise SceneStateError(f"{where} is not finite: {_short(value)}")
        out.append(number)
    return tuple(out)


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _vec3(value: Any, where: str) -> Vec3:
    x, y, z = _numbers(value, 3, where)
    return (x, y, z)


def _rotation(value: Any, where: str) -> Quat:
    x, y, z, w = _numbers(value, 4, where)
    length = math.sqrt(x * x + y * y + z * z + w * w)
    if not length > 0.0 or not math.isfinite(length):
        raise SceneStateError(f"{where} must be a quaternion of non-zero length, got {_short(value)}")
    if abs(length - 1.0) <= UNIT_TOLERANCE:
        return (x, y, z, w)   # kept as is, so that passing a state along never changes it
    return (x / length, y / length, z / length, w / length)


def _scale(value: Any, where: str) -> Vec3:
    scale = _vec3(value, where)
    if any(abs(s) < MIN_SCALE for s in scale):
        raise SceneStateError(f"{where} must be non-zero (at least {MIN_SCALE} in size), got {_short(value)}")
    return scale


def _visible(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise SceneStateError(f"{where} must be true or false, got {_short(value)}")
    return value


def quaternion_matrix(rotation: Iterable[float]) -> np.ndarray:
    """3×3 float64 rotation matrix of a unit quaternion [qx, qy, qz, qw]."""
    x, y, z, w = (float(v) for v in rotation)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def matrix_quaternion(rotation: np.ndarray) -> Quat:
    """Unit quaternion [qx, qy, qz, qw] (qw ≥ 0) of a 3×3 rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4.0)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4.0, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4.0, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4.0, (m[1, 0] - m[0, 1]) / s)
    sign = -1.0 if q[3] < 0.0 else 1.0
    return _rotation([sign * v for v in q], "rotation")


def _named(name: str, build: Any, *args: Any) -> Any:
    """``build(*args)`` with a SceneStateError's message prefixed by ``name.``."""
    try:
        return build(*args)
    except SceneStateError as exc:
        raise SceneStateError(f"{name}.{exc}") from None


@dataclass(frozen=True, slots=True)
class ObjectPatch:
    """Any subset of an object's state; None leaves that field as it is. Construction validates
    (SceneStateError) and normalises the rotation."""

    translation: Vec3 | None = None
    rotation: Quat | None = None
    scale: Vec3 | None = None
    visible: bool | None = None

    def __post_init__(self) -> None:
        for key, check in (("translation", _vec3), ("rotation", _rotation), ("scale", _scale),
                           ("visible", _visible)):
            value = getattr(self, key)
            if value is not None:
                object.__setattr__(self, key, check(value, key))

    @classmethod
    def from_json(cls, data: Any, name: str = "object") -> ObjectPatch:
        """Validate ``{"translation"?, "rotation"?, "scale"?, "visible"?}``; raises SceneStateError
        naming ``name`` and the field."""
        if not isinstance(data, Mapping):
            raise SceneStateError(f"{name}: must be a JSON object, got {type(data).__name__}")
        unknown = sorted(str(key) for key in data if key not in OBJECT_FIELDS)
        if unknown:
            raise SceneStateError(f"{name}: unknown fields {unknown}; expected any of {list(OBJECT_FIELDS)}")
        return _named(name, cls, *(data.get(key) for key in OBJECT_FIELDS))

    def to_json(self) -> dict[str, Any]:
        """The fields that are set."""
        values = {key: getattr(self, key) for key in OBJECT_FIELDS}
        return {key: list(value) if isinstance(value, tuple) else value
                for key, value in values.items() if value is not None}


@dataclass(frozen=True, slots=True)
class ObjectState:
    """One object's local transform and visibility; construction validates (SceneStateError) and
    normalises the rotation, so equal states compare equal."""

    translation: Vec3 = (0.0, 0.0, 0.0)
    rotation: Quat = (0.0, 0.0, 0.0, 1.0)
    scale: Vec3 = (1.0, 1.0, 1.0)
    visible: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "translation", _vec3(self.translation, "translation"))
        object.__setattr__(self, "rotation", _rotation(self.rotation, "rotation"))
        object.__setattr__(self, "scale", _scale(self.scale, "scale"))
        _visible(self.visible, "visible")

    @classmethod
    def from_json(cls, data: Any, name: str = "object") -> ObjectState:
        """A full state from ``{"translation", "rotation", "scale", "visible"}`` (missing fields
        take the identity); raises SceneStateError."""
        return cls().patched(ObjectPatch.from_json(data, name))

    @classmethod
    def from_matrix(cls, matrix: np.ndarray, visible: bool = True) -> ObjectState:
        """Decompose a 4×4 affine ``matrix`` into T·R·S (a mirroring matrix gets a negative x scale;
        shear, which TRS cannot hold, is dropped by the polar decomposition)."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise SceneStateError(f"a transform matrix must be 4x4 and finite, got shape {m.shape}")
        linear = m[:3, :3]
        scale = np.linalg.norm(linear, axis=0)
        if np.linalg.det(linear) < 0.0:
            scale[0] = -scale[0]
        if (np.abs(scale) < MIN_SCALE).any():
            raise SceneStateError(f"transform matrix is singular (scale {scale.tolist()})")
        u, _, vt = np.linalg.svd(linear / scale)
        return cls(_vec3(m[:3, 3], "translation"), matrix_quaternion(u @ vt), _scale(scale, "scale"), visible)

    def patched(self, patch: ObjectPatch) -> ObjectState:
        """This state with the fields ``patch`` sets."""
        changes = {key: getattr(patch, key) for key in OBJECT_FIELDS if getattr(patch, key) is not None}
        return replace(self, **changes) if changes else self

    def matrix(self) -> np.ndarray:
        """4×4 float64 local matrix T·R·S (row-major, ``M @ [x, y, z, 1]``)."""
        out = np.identity(4)
        out[:3, :3] = quaternion_matrix(self.rotation) * np.asarray(self.scale)
        out[:3, 3] = self.translation
        return out

    def to_json(self) -> dict[str, Any]:
        return {"translation": list(self.translation), "rotation": list(self.rotation),
                "scale": list(self.scale), "visible": self.visible}


def _time(value: Any) -> float:
    (time,) = _numbers([value], 1, "time")
    return time


def _version(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SceneStateError(f"{where} must be an integer >= 0, got {_short(value)}")
    return value


def _objects_json(data: Any, where: str) -> dict[str, ObjectState]:
    if not isinstance(data, Mapping):
        raise SceneStateError(f"{where} must be a JSON object of name: state")
    return {str(name): ObjectState.from_json(value, str(name)) for name, value in data.items()}


def _frozen(objects: Mapping[str, ObjectState]) -> Mapping[str, ObjectState]:
    for name, state in objects.items():
        if not isinstance(state, ObjectState):
            raise SceneStateError(f"{name}: expected an ObjectState, got {type(state).__name__}")
    return MappingProxyType(dict(objects))


@dataclass(frozen=True, slots=True)
class StateDelta:
    """What turns state ``base`` into state ``version``: the new ``time`` (s) and the objects whose
    state differs (their full new state)."""

    base: int
    version: int
    time: float
    objects: Mapping[str, ObjectState] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _version(self.base, "delta base")
        _version(self.version, "delta version")
        object.__setattr__(self, "time", _time(self.time))
        object.__setattr__(self, "objects", _frozen(self.objects))

    def __reduce__(self) -> tuple[Any, ...]:
        return StateDelta, (self.base, self.version, self.time, dict(self.objects))

    def to_json(self) -> dict[str, Any]:
        return {"base": self.base, "version": self.version, "time": self.time,
                "objects": {name: state.to_json() for name, state in self.objects.items()}}


@dataclass(frozen=True, slots=True, eq=False)
class SceneState:
    """The scene time (s) and every object's :class:`ObjectState`, at ``version``.

    ``objects`` is read-only and keeps the scene's object order. Two states are equal when their
    time and objects are (the version is a label, not content: :meth:`same_as`)."""

    version: int
    time: float
    objects: Mapping[str, ObjectState]

    def __post_init__(self) -> None:
        _version(self.version, "state version")
        object.__setattr__(self, "time", _time(self.time))
        object.__setattr__(self, "objects", _frozen(self.objects))

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled with its objects as a plain dict (a read-only mapping view cannot be pickled)."""
        return SceneState, (self.version, self.time, dict(self.objects))

    def same_as(self, other: SceneState) -> bool:
        """Same time and the same objects in the same states."""
        return self.time == other.time and dict(self.objects) == dict(other.objects)

    def _known(self, names: Iterable[str]) -> None:
        unknown = [name for name in names if name not in self.objects]
        if unknown:
            raise UnknownObjectError(f"unknown objects: {sorted(unknown)[:10]}")

    def updated(self, changes: Mapping[str, ObjectState], time: float | None = None) -> SceneState:
        """Version + 1 with ``changes`` applied (and ``time``, when given); this very state when
        neither changes anything. Raises UnknownObjectError for a name not in the state."""
        self._known(changes)
        new_time = self.time if time is None else _time(time)
        changed = {name: state for name, state in changes.items() if self.objects[name] != state}
        if not changed and new_time == self.time:
            return self
        return SceneState(self.version + 1, new_time, {**self.objects, **changed})

    def patched(self, patches: Mapping[str, ObjectPatch], time: float | None = None) -> SceneState:
        """:meth:`updated` with each object's state patched by ``patches[name]``."""
        self._known(patches)
        return self.updated({name: self.objects[name].patched(patch) for name, patch in patches.items()}, time)

    def delta_from(self, base: SceneState) -> StateDelta:
        """The delta that turns ``base`` (the same objects) into this state."""
        if base.objects.keys() != self.objects.keys():
            raise SceneStateError("states of different object sets have no delta")
        changed = {name: state for name, state in self.objects.items() if base.objects[name] != state}
        return StateDelta(base.version, self.version, self.time, changed)

    def apply(self, delta: StateDelta) -> SceneState:
        """The state ``delta`` leads to from this one; raises SceneStateError when ``delta`` is based
        on another version or names unknown objects."""
        if delta.base != self.version:
            raise SceneStateError(f"delta {delta.base}→{delta.version} does not apply to state version "
                                  f"{self.version}; a full state is needed")
        self._known(delta.objects)
        return SceneState(delta.version, delta.time, {**self.objects, **delta.objects})

    def to_json(self) -> dict[str, Any]:
        return {"version": self.version, "time": self.time,
                "objects": {name: state.to_json() for name, state in self.objects.items()}}


def state_from_json(data: Any) -> SceneState | StateDelta:
    """A full state (``{"version", "time", "objects"}``) or a delta (the same with ``"base"``);
    raises SceneStateError naming what is wrong."""
    if not isinstance(data, Mapping):
        raise SceneStateError("a scene state must be a JSON object")
    unknown = sorted(str(key) for key in data if key not in ("base", "version", "time", "objects"))
    if unknown:
        raise SceneStateError(f"unknown scene state fields {unknown}")
    for key in ("version", "time", "objects"):
        if key not in data:
            raise SceneStateError(f"scene state lacks {key!r}")
    objects = _objects_json(data["objects"], "scene state objects")
    if "base" in data:
        return StateDelta(_version(data["base"], "delta base"), _version(data["version"], "delta version"),
                          data["time"], objects)
    return SceneState(_version(data["version"], "state version"), data["time"], objects)


class StateLog:
    """The coordinator's scene state: the current version and the last ``history`` versions, from
    which it makes each node's payload (:meth:`payload_for`)."""

    def __init__(self, initial: SceneState, history: int = HISTORY) -> None:
        if history < 1:
            raise ValueError(f"history must be >= 1, got {history}")
        self._history = history
        self._states: OrderedDict[int, SceneState] = OrderedDict([(initial.version, initial)])
        self.current = initial

    def update(self, changes: Mapping[str, ObjectState], time: float | None = None) -> SceneState:
        """Apply ``changes`` (and ``time``) as the next version; returns the current state (the same
        one when nothing changed). Raises UnknownObjectError, and nothing changes."""
        return self._push(self.current.updated(changes, time))

    def patch(self, patches: Mapping[str, ObjectPatch], time: float | None = None) -> SceneState:
        """:meth:`update` with partial changes."""
        return self._push(self.current.patched(patches, time))

    def _push(self, state: SceneState) -> SceneState:
        if state is not self.current:
            self._states[state.version] = self.current = state
            while len(self._states) > self._history:
                self._states.popitem(last=False)
        return state

    def get(self, version: int) -> SceneState | None:
        """Version ``version`` if still kept."""
        return self._states.get(version)

    def payload_for(self, known: int | None, version: int | None = None) -> SceneState | StateDelta:
        """What brings a node whose newest state is version ``known`` (None: it has none) to
        ``version`` (default the current one): a delta when ``known`` is still kept, else the full
        state. Raises SceneStateError when ``version`` is no longer kept."""
        target = self.current if version is None else self._states.get(version)
        if target is None:
            raise SceneStateError(f"state version {version} is no longer kept")
        base = None if known is None else self._states.get(known)
        return target if base is None else target.delta_from(base)


class StateReplica:
    """A render node's copy of the state: each render message's payload is applied on the newest
    state received (messages arrive in order), giving the exact state of that message's frame."""

    def __init__(self) -> None:
        self.current: SceneState | None = None

    def receive(self, payload: SceneState | StateDelta) -> SceneState:
        """The state ``payload`` stands for; raises SceneStateError for a delta without its base. A
        delta that changes nothing gives the very same state object (a renderer keeps its pose)."""
        if isinstance(payload, SceneState):
            self.current = payload
        elif self.current is None:
            raise SceneStateError(f"delta {payload.base}→{payload.version} arrived before any full state")
        elif not (payload.base == payload.version == self.current.version and not payload.objects
                  and payload.time == self.current.time):
            self.current = self.current.apply(payload)
        return self.current
