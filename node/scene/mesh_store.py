"""Meshes the coordinator sent as arrays (issue 33, :mod:`tessera.wire.mesh_update`): kept in memory,
only the newest of each group (a session's steps) of the last :data:`MAX_GROUPS`, and made into a scene as a PLY
file is (one batch, one object, smooth normals computed when none came), with no cache entry. No GL.

A mesh's spec is ``mesh:GROUP:STEP`` (:mod:`server.mesh_updates`); a ``load_scene`` of a step
superseded before its load began fails at once, which the coordinator ignores (its session shows
the newer step by then).
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
#: Most groups whose newest mesh is kept (the oldest is dropped past it: a closed session's).
MAX_GROUPS = 16


def is_mesh(spec: str | None) -> bool:
    return spec is not None and spec.startswith(MESH_PREFIX)


def group_of(spec: str) -> str:
    """``mesh:GROUP:STEP`` → ``GROUP``."""
    return spec[len(MESH_PREFIX):].rsplit(":", 1)[0]


class MeshStore:
    """The newest mesh message of each group, by spec; filled on the event loop, read by the loader
    thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._newest: dict[str, tuple[str, bytes]] = {}

    def receive(self, data: bytes) -> str:
        """Keep mesh message ``data`` (it supersedes its group's older one); returns its spec.
        MeshError when it is not a mesh message with a ``mesh:`` spec (only its header is read here)."""
        header, _ = mesh_header(data)
        spec = header.get("scene")
        if not isinstance(spec, str) or not is_mesh(spec):
            raise MeshError(f"a mesh message names its scene mesh:GROUP:STEP, got {spec!r}")
        with self._lock:
            self._newest.pop(group_of(spec), None)
            self._newest[group_of(spec)] = (spec, data)
            while len(self._newest) > MAX_GROUPS:
                del self._newest[next(iter(self._newest))]
        return spec

    def scene(self, spec: str, face_limit: int) -> SceneData:
        """The scene of mesh ``spec``, split into chunks of at most ``face_limit`` faces. SceneError
        when it never came (or was dropped) or a newer one of its group did."""
        with self._lock:
            newest = self._newest.get(group_of(spec))
            if newest is None or newest[0] != spec:
                raise SceneError(f"{spec}: no such mesh here (meshes sent as arrays are not kept across restarts: "
                                 "send it again)" if newest is None else
                                 f"{spec}: superseded by a newer mesh before it was loaded")
        try:
            _, mesh = unpack_mesh(newest[1])
        except MeshError as exc:
            raise SceneError(f"{spec}: {exc}") from None
        colors = None if mesh.colors is None else mesh.colors.astype(np.float32) / np.float32(255.0)
        normals = None if mesh.normals is None else normalized(mesh.normals.copy())
        batch = MeshBatch(name=MESH_OBJECT, positions=mesh.positions.copy(), normals=normals,
                          faces=mesh.faces.copy(), colors=colors)
        return SceneData.from_batches(spec, [batch], face_limit, [SceneObject(MESH_OBJECT)])
