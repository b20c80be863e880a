"""Meshes sent as arrays (issue 33): each session's mesh shown, the one waiting, and when nodes get it.

A mesh becomes a scene of its own, spec ``mesh:GROUP:STEP`` (``GROUP`` drawn once per session,
``STEP`` per mesh: never the session's id, which drives it, and never a spec a node held before a
restart), shown by switching the session to it (:meth:`RenderService.switch_scene`): the session's
frames in flight are dropped, every node loads the mesh at once (from memory: tens of ms for 100k
triangles), and the next frame published is drawn from it on every tile, so no frame mixes two
steps. A node gets the mesh's bytes right before each ``load_scene`` of its spec
(:meth:`MeshUpdates.before_load`: a node that joins later too) and keeps the newest of a group
(:mod:`node.scene.mesh_store`).

A step is switched in only once the step before it reached a published frame: switching at once
would drop that step's frames in flight, and steps coming faster than a frame is drawn would then
never show. A step sent meanwhile waits (its request too), one a session: a newer one takes its
place, and both requests answer the frame id from which the newer one shows. A step not shown within
:data:`MESH_WAIT_S` (its load failed) is passed over.
"""

from __future__ import annotations

import asyncio
import secrets
from dataclasses import dataclass
from typing import Protocol

from server.nodes import NodeLink
from server.sessions import Session
from tessera.scheduling.scheduler import FrameScheduler
from tessera.wire.mesh_update import MeshArrays, pack_mesh

#: Spec prefix of a mesh sent as arrays; the node reads it from memory (:mod:`node.scene.mesh_store`).
MESH_PREFIX = "mesh:"
#: What a session showing a mesh is called in ``/api/sessions``.
MESH_NAME = "mesh"
#: Longest wait of a step for the one before it to be shown before it is switched in anyway (s).
MESH_WAIT_S = 10.0


class SessionGone(RuntimeError):
    """The session closed while its mesh waited."""


class MeshHost(Protocol):
    """What the meshes need of the service."""

    nodes: dict[int, NodeLink]
    sessions: dict[str, Session]

    @property
    def scheduler(self) -> FrameScheduler: ...

    def switch_scene(self, session: Session, name: str, spec: str, fetch: tuple[str, str] | None) -> int: ...

    def apply(self) -> None: ...


@dataclass(eq=False)
class SessionMeshes:
    """A session's meshes: the step switched in last (its spec, message and first frame id, and
    whether a frame of it was published), and the step waiting with the future its requests await."""

    group: str
    spec: str | None = None
    data: bytes = b""
    first: int = 0
    shown: bool = True
    waiting: tuple[str, bytes] | None = None
    answer: asyncio.Future[int] | None = None


class MeshUpdates:
    """The meshes of each session of ``service``, packed for the nodes."""

    def __init__(self, service: MeshHost) -> None:
        self.service = service
        self._sessions: dict[str, SessionMeshes] = {}

    async def update(self, session: Session, mesh: MeshArrays) -> int:
        """``session`` shows ``mesh`` from the frame whose id this returns on (a newer mesh from
        there on, when one took its place while it waited); SessionGone when the session closed."""
        self._forget_gone()
        state = self._sessions.setdefault(session.id, SessionMeshes(secrets.token_hex(6)))
        spec = f"{MESH_PREFIX}{state.group}:{secrets.token_hex(4)}"
        data = pack_mesh(mesh, scene=spec)
        if state.shown or session.scene != state.spec or session.state == "error":
            return self._switch(session, state, spec, data)
        state.waiting = (spec, data)
        if state.answer is None:
            state.answer = asyncio.get_running_loop().create_future()
        answer = state.answer
        try:
            return await asyncio.wait_for(asyncio.shield(answer), MESH_WAIT_S)
        except TimeoutError:
            self._advance(session.id)   # the step before was not shown in time: this one goes in
            return await answer

    def published(self, session_id: str, frame_id: int) -> None:
        """A frame of the session was published: the step it shows is on screen; the one waiting
        goes in next (once the publishing is done)."""
        state = self._sessions.get(session_id)
        if state is not None and not state.shown and frame_id >= state.first:
            state.shown = True
            if state.waiting is not None:
                asyncio.get_running_loop().call_soon(self._advance, session_id)

    def before_load(self, node_id: int, spec: str | None) -> None:
        """A ``load_scene`` of ``spec`` goes to node ``node_id``: a mesh's bytes go first."""
        link = self.service.nodes.get(node_id)
        if spec is None or not spec.startswith(MESH_PREFIX) or link is None:
            return
        for state in self._sessions.values():
            if state.spec == spec:
                link.send_bytes(state.data)

    def _advance(self, session_id: str) -> None:
        """Switch the session to its step waiting, if any, and answer that step's requests."""
        state = self._sessions.get(session_id)
        if state is None or state.waiting is None or state.answer is None:
            return
        (spec, data), answer = state.waiting, state.answer
        state.waiting = state.answer = None
        session = self.service.sessions.get(session_id)
        if session is None:
            answer.set_exception(SessionGone("the session was closed"))
            return
        first = self._switch(session, state, spec, data)
        if not answer.done():
            answer.set_result(first)

    def _switch(self, session: Session, state: SessionMeshes, spec: str, data: bytes) -> int:
        state.spec, state.data, state.shown = spec, data, False
        state.first = self.service.switch_scene(session, MESH_NAME, spec, None)
        self.service.scheduler.load_now(session.id)   # from memory: every node at once
        self.service.apply()
        return state.first

    def _forget_gone(self) -> None:
        """Drop what is kept of sessions closed since (their requests waiting answer SessionGone)."""
        for session_id in [i for i in self._sessions if i not in self.service.sessions]:
            state = self._sessions.pop(session_id)
            if state.answer is not None and not state.answer.done():
                state.answer.set_exception(SessionGone("the session was closed"))
