"""Meshes sent as arrays (issue 33): each session's newest one, and when nodes get it.

A mesh becomes a scene of its own, spec ``mesh:GROUP:STEP`` (``GROUP`` drawn once per session,
``STEP`` per mesh: never the session's id, which drives it, and never a spec a node held before a
restart), shown by switching the session to it (:meth:`RenderService.switch_scene`): the session's
frames in flight are dropped, nodes load the mesh one after the other as they load any new scene,
and the next frame published is drawn from it on every tile, so no frame mixes two steps. A node
gets the mesh's bytes right before each ``load_scene`` of its spec (:meth:`MeshUpdates.before_load`:
a node that joins later too), and keeps only the newest of a group (:mod:`node.scene.mesh_store`).
The coordinator keeps one mesh a session: a newer one supersedes it, shown or not.
"""

from __future__ import annotations

import secrets
from typing import Protocol

from server.nodes import NodeLink
from server.sessions import Session
from tessera.wire.mesh_update import MeshArrays, pack_mesh

#: Spec prefix of a mesh sent as arrays; the node reads it from memory (:mod:`node.scene.mesh_store`).
MESH_PREFIX = "mesh:"
#: What a session showing a mesh is called in ``/api/sessions``.
MESH_NAME = "mesh"


class MeshHost(Protocol):
    """What the meshes need of the service."""

    nodes: dict[int, NodeLink]
    sessions: dict[str, Session]

    def switch_scene(self, session: Session, name: str, spec: str, fetch: tuple[str, str] | None) -> int: ...


class MeshUpdates:
    """The newest mesh of each session of ``service``, packed for the nodes."""

    def __init__(self, service: MeshHost) -> None:
        self.service = service
        self._groups: dict[str, str] = {}
        #: session id → (spec, the message nodes get).
        self._latest: dict[str, tuple[str, bytes]] = {}

    def update(self, session: Session, mesh: MeshArrays) -> int:
        """``session`` shows ``mesh`` from the frame whose id this returns on."""
        self._forget_gone()
        group = self._groups.setdefault(session.id, secrets.token_hex(6))
        spec = f"{MESH_PREFIX}{group}:{secrets.token_hex(4)}"
        self._latest[session.id] = (spec, pack_mesh(mesh, scene=spec))
        return self.service.switch_scene(session, MESH_NAME, spec, None)

    def before_load(self, node_id: int, spec: str | None) -> None:
        """A ``load_scene`` of ``spec`` goes to node ``node_id``: a mesh's bytes go first."""
        if spec is None or not spec.startswith(MESH_PREFIX):
            return
        link = self.service.nodes.get(node_id)
        for shown, data in self._latest.values():
            if shown == spec and link is not None:
                link.send_bytes(data)

    def _forget_gone(self) -> None:
        """Drop the meshes of sessions closed or showing something else since."""
        for session_id, (spec, _) in list(self._latest.items()):
            session = self.service.sessions.get(session_id)
            if session is None or session.scene != spec:
                del self._latest[session_id]
                if session is None:
                    self._groups.pop(session_id, None)
