"""The scene's named objects and their hierarchy (issue 11: objects; glTF 2.0 §3.5 nodes and
transforms), and what a :class:`tessera.scene.state.SceneState` makes of them: world matrices,
model matrices, visibility and bounds.

Pure: numpy only, no GL, no I/O; render nodes and the coordinator compute the same numbers from
the same state.

An object is a glTF node (or, for a PLY/OBJ/STL file, the whole file; for a built-in scene, one
generated object). Its state is its *local* transform, relative to its parent; its world matrix is
the parent's world matrix times its local matrix. Geometry is loaded once, baked into world space
at the *base* pose (the file's own transforms), so what moves it is the object's **model matrix**:
world(state) · world(base)⁻¹, the identity at the base pose. An object is drawn when it and all its
ancestors are visible.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tessera.scene.state import (
    OBJECT_FIELDS,
    ObjectPatch,
    ObjectState,
    SceneState,
    SceneStateError,
    UnknownObjectError,
)

#: The 8 corners of a box as (min, max) selectors per axis: (8, 3) 0/1.
_CORNERS = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])


@dataclass(frozen=True, eq=False)
class SceneObject:
    """One object: ``name`` (unique), ``parent`` index (−1 for a root; a parent comes before its
    children), ``base`` local state as loaded, the world-space ``bounds`` (2, 3) float64 of its own
    geometry at the base pose (None when it has none) and its ``triangles``."""

    name: str
    parent: int = -1
    base: ObjectState = field(default_factory=ObjectState)
    bounds: np.ndarray | None = None
    triangles: int = 0

    def to_json(self, graph: ObjectGraph, state: ObjectState | None = None) -> dict[str, Any]:
        """``{"name", "parent" (a name or null), "translation", "rotation", "scale", "visible",
        "bounds" ([[x0, y0, z0], [x1, y1, z1]] or null), "triangles"}`` with ``state`` (default
        the base state)."""
        return {"name": self.name, "parent": None if self.parent < 0 else graph.objects[self.parent].name,
                **(state or self.base).to_json(),
                "bounds": None if self.bounds is None else self.bounds.tolist(), "triangles": self.triangles}


class ObjectGraph:
    """The scene's objects in hierarchy order (parents first)."""

    def __init__(self, objects: Sequence[SceneObject]) -> None:
        if not objects:
            raise SceneStateError("a scene has at least one object")
        self.objects = tuple(objects)
        self.index: dict[str, int] = {}
        for number, item in enumerate(self.objects):
            if item.name in self.index:
                raise SceneStateError(f"object name {item.name!r} is used twice")
            if not -1 <= item.parent < number:
                raise SceneStateError(f"object {item.name!r}: parent {item.parent} does not come before it")
            self.index[item.name] = number
        self.parents = np.array([item.parent for item in self.objects], np.int64)
        self.base = self.base_state()
        self._base_inverse = np.linalg.inv(self.world_matrices(self.base))

    def __len__(self) -> int:
        return len(self.objects)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(item.name for item in self.objects)

    def lookup(self, name: str) -> int:
        """The index of object ``name``; raises UnknownObjectError."""
        number = self.index.get(name)
        if number is None:
            raise UnknownObjectError(f"unknown object {name!r}")
        return number

    def base_state(self, time: float = 0.0) -> SceneState:
        """Version 0: every object at its base state, at ``time`` (s)."""
        return SceneState(0, time, {item.name: item.base for item in self.objects})

    def posed(self, time: float, animated: Mapping[str, ObjectPatch] | None = None,
              overrides: Mapping[str, ObjectPatch] | None = None, version: int = 0) -> SceneState:
        """The state at ``time`` (s): each object's base state, patched by its ``animated`` values
        (animation channels sampled at ``time``), then by its ``overrides`` (a user's pose wins over
        the animation). Raises UnknownObjectError."""
        layers = [animated or {}, overrides or {}]
        for patches in layers:
            for name in patches:
                self.lookup(name)
        objects = {}
        for item in self.objects:
            state = item.base
            for patches in layers:
                patch = patches.get(item.name)
                if patch is not None:
                    state = state.patched(patch)
            objects[item.name] = state
        return SceneState(version, time, objects)

    def _check(self, state: SceneState) -> None:
        if len(state.objects) != len(self.objects) or any(name not in self.index for name in state.objects):
            raise SceneStateError("the state's objects are not this scene's objects")

    def world_matrices(self, state: SceneState) -> np.ndarray:
        """(N, 4, 4) float64 world matrices of the objects (hierarchy order) in ``state``."""
        self._check(state)
        world = np.empty((len(self.objects), 4, 4))
        for number, item in enumerate(self.objects):
            local = state.objects[item.name].matrix()
            world[number] = local if item.parent < 0 else world[item.parent] @ local
        return world

    def model_matrices(self, state: SceneState) -> np.ndarray:
        """(N, 4, 4) float64: what moves each object's base-pose world-space geometry to ``state``;
        exactly the identity for an object whose transform and ancestors' are at their base."""
        self._check(state)
        moved = np.empty(len(self.objects), dtype=bool)
        for number, item in enumerate(self.objects):
            own = state.objects[item.name]
            moved[number] = (_transform(own) != _transform(item.base)) or (item.parent >= 0 and moved[item.parent])
        model = np.broadcast_to(np.identity(4), (len(self.objects), 4, 4)).copy()
        if moved.any():
            model[moved] = self.world_matrices(state)[moved] @ self._base_inverse[moved]
        return model

    def visibility(self, state: SceneState) -> np.ndarray:
        """(N,) bool: the object and all its ancestors are visible in ``state``."""
        self._check(state)
        shown = np.empty(len(self.objects), dtype=bool)
        for number, item in enumerate(self.objects):
            own = state.objects[item.name].visible
            shown[number] = own and (item.parent < 0 or bool(shown[item.parent]))
        return shown

    def moved(self, state: SceneState) -> np.ndarray:
        """(N,) bool: the object's model matrix in ``state`` is not the identity."""
        return ~(self.model_matrices(state) == np.identity(4)).all(axis=(1, 2))

    def bounds(self, state: SceneState) -> np.ndarray | None:
        """World AABB (2, 3) float64 of the visible objects' geometry in ``state`` (each object's base
        box moved by its model matrix: a box around the moved box); None when nothing is visible."""
        shown = self.visibility(state)
        numbers = [n for n, item in enumerate(self.objects) if item.bounds is not None and shown[n]]
        if not numbers:
            return None
        boxes = np.stack([box for n in numbers if (box := self.objects[n].bounds) is not None])
        moved = transform_boxes(boxes, self.model_matrices(state)[numbers])
        return np.stack([moved[:, 0].min(axis=0), moved[:, 1].max(axis=0)])

    def to_json(self, state: SceneState | None = None) -> list[dict[str, Any]]:
        """Every object's JSON (:meth:`SceneObject.to_json`) with its state in ``state``."""
        return [item.to_json(self, None if state is None else state.objects[item.name]) for item in self.objects]

    @classmethod
    def from_json(cls, data: Sequence[Mapping[str, Any]]) -> ObjectGraph:
        """The graph :meth:`to_json` describes (its base states, parents named before their
        children, bounds and triangles), numbers kept bit for bit; raises SceneStateError."""
        objects: list[SceneObject] = []
        index: dict[str, int] = {}
        for entry in data:
            name = str(entry.get("name"))
            parent = entry.get("parent")
            if parent is not None and parent not in index:
                raise SceneStateError(f"object {name!r}: parent {parent!r} does not come before it")
            base = ObjectState.from_json({key: entry[key] for key in OBJECT_FIELDS if key in entry}, name)
            bounds = entry.get("bounds")
            box = None if bounds is None else np.asarray(bounds, dtype=np.float64)
            if box is not None and (box.shape != (2, 3) or not np.isfinite(box).all()):
                raise SceneStateError(f"object {name!r}: bounds must be [[x0, y0, z0], [x1, y1, z1]]")
            triangles = entry.get("triangles", 0)
            if isinstance(triangles, bool) or not isinstance(triangles, int) or triangles < 0:
                raise SceneStateError(f"object {name!r}: triangles must be an integer >= 0")
            index.setdefault(name, len(objects))
            objects.append(SceneObject(name, -1 if parent is None else index[parent], base, box, triangles))
        return cls(objects)

    def world_bounds(self, state: SceneState) -> list[np.ndarray | None]:
        """Each object's own geometry's world box (2, 3) in ``state`` (None: it has none)."""
        models = self.model_matrices(state)
        return [None if item.bounds is None else transform_boxes(item.bounds[None], model)[0]
                for item, model in zip(self.objects, models, strict=True)]


def _transform(state: ObjectState) -> tuple[tuple[float, ...], ...]:
    return state.translation, state.rotation, state.scale


def transform_boxes(boxes: np.ndarray, matrices: np.ndarray) -> np.ndarray:
    """Axis-aligned boxes (K, 2, 3) [min, max] moved by affine ``matrices`` (K, 4, 4) or one (4, 4):
    the boxes (K, 2, 3) float64 around the 8 moved corners of each."""
    boxes = np.asarray(boxes, dtype=np.float64)
    corners = np.where(_CORNERS[None, :, :] == 1, boxes[:, 1:2, :], boxes[:, 0:1, :])   # (K, 8, 3)
    matrices = np.broadcast_to(np.asarray(matrices, dtype=np.float64), (len(boxes), 4, 4))
    moved = corners @ np.swapaxes(matrices[:, :3, :3], 1, 2) + matrices[:, None, :3, 3]
    return np.stack([moved.min(axis=1), moved.max(axis=1)], axis=1)
