"""Meshes the coordinator sent as arrays (issue 33, :mod:`tessera.wire.mesh_update`): kept in memory,
per group (a session's steps) of the last :data:`MAX_GROUPS` the newest and the one its header says
to keep (the step shown while the newest loads: double-buffered), and made into a scene as a PLY
file is (one batch, one object, smooth normals computed when none came), with no cache entry and no
levels of detail. No GL.

A simulation's steps mostly move the vertices of the same faces: a step whose faces are the step
before's keeps that step's octree chunks (:func:`node.scene.octree.moved_split`: the vertex and face
orders as they were, boxes and normals new; 10 ms for 100k triangles instead of 22, measured on the
2-core CI machine) until the vertices have moved so far that its chunks' boxes, summed, grew to
:data:`RESPLIT_SPREAD` times what a fresh split had (then it is split afresh).

A mesh's spec is ``mesh:GROUP:STEP`` (:mod:`server.mesh_updates`); a ``load_scene`` of a step
superseded before its load began fails at once, which the coordinator ignores (its session shows
the newer step by then). The coordinator checked the arrays before sending them: only the layout
is checked again here.
"""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass

import numpy as np

from node.scene.chunks import octree_chunks
from node.scene.data import SceneData
from node.scene.mesh import MeshBatch, SceneError
from node.scene.normals import normalized
from node.scene.octree import ChunkSplit, moved_split
from tessera.scene.graph import SceneObject
from tessera.wire.mesh_update import MeshError, is_mesh_spec, mesh_group, mesh_header, unpack_mesh

#: The one object of a mesh scene.
MESH_OBJECT = "mesh"
#: Most groups whose meshes are kept (the oldest is dropped past it: a closed session's).
MAX_GROUPS = 16
#: A step keeps the chunks of the step before while their boxes' diagonals, summed over the mesh's
#: diagonal, stay within this many times those of the last fresh split.
RESPLIT_SPREAD = 1.5


def spread(split: ChunkSplit) -> float:
    """How spread ``split``'s chunks are: their boxes' diagonals summed, over the mesh's diagonal."""
    boxes = split.bounds.astype(np.float64)
    whole = float(np.linalg.norm(boxes[:, 1].max(axis=0) - boxes[:, 0].min(axis=0)))
    return float(np.linalg.norm(boxes[:, 1] - boxes[:, 0], axis=1).sum()) / max(whole, np.finfo(np.float64).tiny)


@dataclass(frozen=True, slots=True)
class KeptSplit:
    """A group's last split: the ``faces`` (F, 3) it split (as sent), with ``face_limit``, its
    chunks (``split``, without positions and normals) and the :func:`spread` of the last fresh one."""

    faces: np.ndarray
    face_limit: int
    split: ChunkSplit
    fresh_spread: float


class MeshStore:
    """Each group's newest mesh message and the one it keeps, by spec; filled on the event loop,
    read by the loader and GL threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._groups: dict[str, dict[str, bytes]] = {}
        self._splits: dict[str, KeptSplit] = {}

    def receive(self, data: bytes) -> str:
        """Keep mesh message ``data``: its group keeps it and the spec its header names ``keep``
        (if held), nothing else. Returns its spec; MeshError when it is not a mesh message with a
        ``mesh:`` spec (only its header is read here)."""
        header, _ = mesh_header(data)
        spec, keep = header.get("scene"), header.get("keep")
        if not isinstance(spec, str) or not is_mesh_spec(spec):
            raise MeshError(f"a mesh message names its scene mesh:GROUP:STEP, got {spec!r}")
        group = mesh_group(spec)
        with self._lock:
            held = self._groups.pop(group, {})
            self._groups[group] = {**({keep: held[keep]} if keep in held else {}), spec: data}
            while len(self._groups) > MAX_GROUPS:
                self._splits.pop(gone := next(iter(self._groups)), None)
                del self._groups[gone]
        return spec

    def live(self, spec: str) -> bool:
        """Whether mesh ``spec`` is one its group keeps (else it was superseded, or never came)."""
        with self._lock:
            return spec in self._groups.get(mesh_group(spec), {})

    def scene(self, spec: str, face_limit: int) -> SceneData:
        """The scene of mesh ``spec``, split into chunks of at most ``face_limit`` faces. SceneError
        when it never came (or was dropped) or newer ones of its group took its place."""
        with self._lock:
            held = self._groups.get(mesh_group(spec))
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
        return SceneData.from_batches(spec, [batch], face_limit, [SceneObject(MESH_OBJECT)],
                                      splitter=lambda batch, limit: self._split(mesh_group(spec), batch, limit))

    def _split(self, group: str, batch: MeshBatch, face_limit: int) -> ChunkSplit:
        """``batch``'s chunks: the group's last split moved to its vertices when it has the same
        faces and that split is still compact, else a fresh octree split (kept for the next step)."""
        with self._lock:
            kept = self._splits.get(group)
        if kept is not None and kept.face_limit == face_limit and np.array_equal(kept.faces, batch.faces):
            split = moved_split(kept.split, batch.positions, normals=batch.normals is None)
            if spread(split) <= RESPLIT_SPREAD * kept.fresh_spread:
                return split
        split = octree_chunks(batch, face_limit)
        bare = dataclasses.replace(split, positions=None, normals=None)
        with self._lock:
            if group in self._groups:
                self._splits[group] = KeptSplit(batch.faces, face_limit, bare, spread(split))
        return split
