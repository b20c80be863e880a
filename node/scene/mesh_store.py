"""Meshes the coordinator sent as arrays (issue 33, :mod:`tessera.wire.mesh_update`): kept in memory,
per group (a session's steps) of the last :data:`MAX_GROUPS` the newest and the one its header says
to keep (the step shown while the newest loads: double-buffered), and made into a scene as a PLY
file is (one batch, one object, smooth normals computed when none came), with no cache entry and no
levels of detail. No GL.

A mesh's spec is ``mesh:GROUP:STEP`` (:mod:`server.mesh_updates`); a ``load_scene`` of a step
superseded before its load began fails at once, which the coordinator ignores (its session shows
the newer step by then). The coordinator checked the arrays before sending them: only the layout
is checked again here.
"""

from __future__ import annotations

import threading

import numpy as np

from node.scene.data import SceneData
from node.scene.mesh import MeshBatch, SceneError
from node.scene.normals import normalized
from tessera.scene.graph import SceneObject
from tessera.wire.mesh_update import MeshError, mesh_header, unpack_mesh

#: Spec prefix of a mesh sent as arrays.
MESH_PREFIX = "mesh:"
#: The one object of a mesh scene.
MESH_OBJECT = "mesh"
#: Most groups whose meshes are kept (the oldest is dropped past it: a closed session's).
MAX_GROUPS = 16


def is_mesh(spec: str | None) -> bool:
    return spec is not None and spec.startswith(MESH_PREFIX)


def group_of(spec: str) -> str:
    """``mesh:GROUP:STEP`` → ``GROUP``."""
    return spec[len(MESH_PREFIX):].rsplit(":", 1)[0]


class MeshStore:
    """Each group's newest mesh message and the one it keeps, by spec; filled on the event loop,
    read by the loader and GL threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._groups: dict[str, dict[str, bytes]] = {}

    def receive(self, data: bytes) -> str:
        """Keep mesh message ``data``: its group keeps it and the spec its header names ``keep``
        (if held), nothing else. Returns its spec; MeshError when it is not a mesh message with a
        ``mesh:`` spec (only its header is read here)."""
        header, _ = mesh_header(data)
        spec, keep = header.get("scene"), header.get("keep")
        if not isinstance(spec, str) or not is_mesh(spec):
            raise MeshError(f"a mesh message names its scene mesh:GROUP:STEP, got {spec!r}")
        group = group_of(spec)
        with self._lock:
            held = self._groups.pop(group, {})
            self._groups[group] = {**({keep: held[keep]} if keep in held else {}), spec: data}
            while len(self._groups) > MAX_GROUPS:
                del self._groups[next(iter(self._groups))]
        return spec

    def live(self, spec: str) -> bool:
        """Whether mesh ``spec`` is one its group keeps (else it was superseded, or never came)."""
        with self._lock:
            return spec in self._groups.get(group_of(spec), {})

    def scene(self, spec: str, face_limit: int) -> SceneData:
        """The scene of mesh ``spec``, split into chunks of at most ``face_limit`` faces. SceneError
        when it never came (or was dropped) or newer ones of its group took its place."""
        with self._lock:
            held = self._groups.get(group_of(spec))
            data = None if held is None else held.get(spec)
        if data is None:
            raise SceneError(f"{spec}: no such mesh here (meshes sent as arrays are not kept across restarts: "
                             "send it again)" if held is None else
                             f"{spec}: superseded by a newer mesh before it was loaded")
        try:
            _, mesh = unpack_mesh(data, checked=False)
        except MeshError as exc:
            raise SceneError(f"{spec}: {exc}") from None
        colors = None if mesh.colors is None else mesh.colors.astype(np.float32) / np.float32(255.0)
        normals = None if mesh.normals is None else normalized(mesh.normals.copy())
        batch = MeshBatch(name=MESH_OBJECT, positions=mesh.positions.copy(), normals=normals,
                          faces=mesh.faces.copy(), colors=colors)
        return SceneData.from_batches(spec, [batch], face_limit, [SceneObject(MESH_OBJECT)])
