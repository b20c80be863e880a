"""Meshes sent as arrays (issue 33): each session's mesh shown, the one waiting, and when nodes get it.

A mesh becomes a scene of its own, spec ``mesh:GROUP:STEP`` (``GROUP`` drawn once per session,
``STEP`` per mesh: never the session's id, which drives it, and never a spec a node held before a
restart), shown by switching the session to it (:meth:`RenderService.switch_scene`): the session's
frames in flight are dropped, and the next frame published is drawn from it on every tile, so no
frame mixes two steps. A node gets the mesh's bytes (once) before the ``load_scene`` of its spec
(:meth:`MeshUpdates.before_load`: a node that joins later too) and keeps the newest of a group and
the one shown (:mod:`node.scene.mesh_store`).

A step is switched in only once the step before it reached a published frame: switching at once
would drop that step's frames in flight, and steps coming faster than a frame is drawn would then
never show. A step sent meanwhile waits (its request too), one a session: a newer one takes its
place, and both requests answer the frame id from which the newer one shows. While it waits the
nodes load it beside the step shown (double-buffered, where every node holds the whole scene), and
the step shown is drawn once, without settle frames or a still; once shown, the step waiting is
switched in on the nodes that hold it already, all at once, with no round trip. Meanwhile no other
session's still sample starts (:meth:`FrameScheduler.rest`), and a step switched in keeps the
partition the balancer reached on the steps before. A step not shown within :data:`MESH_WAIT_S`
(its load failed) is passed over.
"""

from __future__ import annotations

import asyncio
import secrets
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from server.nodes import NodeLink
from server.sessions import Session
from server.settings import Settings
from tessera.geometry import Camera
from tessera.scheduling.scheduler import FrameScheduler
from tessera.wire.mesh_update import MESH_PREFIX, is_mesh_spec, mesh_group, with_header
from tessera.wire.messages import LoadScene, SceneReady

#: What a session showing a mesh is called in ``/api/sessions``.
MESH_NAME = "mesh"
#: Longest wait of a step for the one before it to be shown before it is switched in anyway (s).
MESH_WAIT_S = 10.0
#: Longest wait of a step shown for the next one's loads ahead before it goes in anyway (s).
LOAD_AHEAD_WAIT_S = 1.0
#: Modes whose nodes each hold the whole scene: a step waiting is loaded ahead there.
WHOLE_SCENE_MODES = ("sort-first", "hybrid")


class SessionGone(RuntimeError):
    """The session closed while its mesh waited."""


class MeshHost(Protocol):
    """What the meshes need of the service."""

    nodes: dict[int, NodeLink]
    sessions: dict[str, Session]

    @property
    def settings(self) -> Settings: ...

    @property
    def scheduler(self) -> FrameScheduler: ...

    def switch_scene(self, session: Session, name: str, spec: str, fetch: tuple[str, str] | None,
                     camera: Camera | None = None, held: Mapping[int, SceneReady] | None = None,
                     keep_partition: bool = False) -> int: ...

    def load_message(self, scene: str | None) -> LoadScene: ...

    def apply(self) -> None: ...


@dataclass(eq=False)
class MeshStep:
    """A step: its spec, its message for the nodes, the nodes sent it and those that hold it
    already (loaded ahead) with their ``scene_ready``."""

    spec: str
    data: bytes
    sent: set[int] = field(default_factory=set)
    held: dict[int, SceneReady] = field(default_factory=dict)
    failed: set[int] = field(default_factory=set)

    def loading(self, nodes: Collection[int]) -> bool:
        """Whether a node of ``nodes`` sent it ahead has not answered yet."""
        return any(n in nodes and n not in self.held and n not in self.failed for n in self.sent)


@dataclass(eq=False)
class SessionMeshes:
    """A session's meshes: the step switched in last (and its first frame id, and whether a frame
    of it was published), and the step waiting with the future its requests await."""

    group: str
    step: MeshStep | None = None
    first: int = 0
    shown: bool = True
    waiting: MeshStep | None = None
    answer: asyncio.Future[int] | None = None


class MeshUpdates:
    """The meshes of each session of ``service``, packed for the nodes."""

    def __init__(self, service: MeshHost) -> None:
        self.service = service
        self._sessions: dict[str, SessionMeshes] = {}

    async def update(self, session: Session, data: bytes) -> int:
        """``session`` shows mesh message ``data`` (checked already) from the frame whose id this
        returns on (a newer mesh from there on, when one took its place while it waited);
        SessionGone when the session closed."""
        self._forget_gone()
        state = self._sessions.setdefault(session.id, SessionMeshes(secrets.token_hex(6)))
        spec = f"{MESH_PREFIX}{state.group}:{secrets.token_hex(4)}"
        kept = None if state.step is None else state.step.spec
        step = MeshStep(spec, with_header(data, scene=spec, keep=kept))
        if state.shown or session.scene != kept or session.state == "error":
            return self._switch(session, state, step)
        state.waiting = step
        self._load_ahead(session, step)
        if state.answer is None:
            state.answer = asyncio.get_running_loop().create_future()
        answer = state.answer
        try:
            return await asyncio.wait_for(asyncio.shield(answer), MESH_WAIT_S)
        except TimeoutError:
            self._advance(session.id)   # the step before was not shown in time: this one goes in
            return await answer

    def steps_shown(self) -> dict[str, MeshStep]:
        """The step each session shows (switched in last), by session id: what a restart restores."""
        return {i: state.step for i, state in self._sessions.items() if state.step is not None
                and (session := self.service.sessions.get(i)) is not None and session.scene == state.step.spec}

    def restore(self, session_id: str, spec: str, data: bytes) -> None:
        """Session ``session_id`` shows mesh ``spec`` (its message ``data``), as before a restart:
        nodes get its bytes before they load it."""
        group = mesh_group(spec)
        self._sessions[session_id] = SessionMeshes(group, MeshStep(spec, data))

    def published(self, session_id: str, frame_id: int) -> None:
        """A frame of the session was published: the step it shows is on screen; the one waiting
        goes in next (once the publishing is done)."""
        state = self._sessions.get(session_id)
        if state is not None and not state.shown and frame_id >= state.first:
            state.shown = True
            if state.waiting is not None:
                asyncio.get_running_loop().call_soon(self._advance_when_held, session_id)

    def before_load(self, node_id: int, spec: str | None) -> None:
        """A ``load_scene`` of ``spec`` goes to node ``node_id``: a mesh's bytes go first, unless
        the node has them."""
        link = self.service.nodes.get(node_id)
        if not is_mesh_spec(spec) or link is None:
            return
        for state in self._sessions.values():
            if state.step is not None and state.step.spec == spec and node_id not in state.step.sent:
                state.step.sent.add(node_id)
                link.send_bytes(state.step.data)

    def loaded_ahead(self, node_id: int, message: SceneReady) -> bool:
        """Node ``node_id`` holds a step waiting (``message`` its ``scene_ready``): kept for its
        switch. False when ``message`` is of no step waiting."""
        return self._answered(node_id, message.scene, message)

    def failed_ahead(self, node_id: int, spec: str | None) -> bool:
        """Node ``node_id`` could not load mesh ``spec``: True when no session shows it (a step
        waiting, which the node then loads when it is switched in, or one passed over: no fault)."""
        sessions = self.service.sessions.values()
        if not is_mesh_spec(spec) or any(s.scene == spec for s in sessions):
            return False
        self._answered(node_id, spec, None)
        return True

    def _answered(self, node_id: int, spec: str | None, ready: SceneReady | None) -> bool:
        """Node ``node_id`` answered the load ahead of ``spec`` (``ready``; None: it failed); the
        step goes in if it was shown and waited for that answer. False: no step waiting is ``spec``."""
        for session_id, state in self._sessions.items():
            if state.waiting is not None and state.waiting.spec == spec:
                if ready is None:
                    state.waiting.failed.add(node_id)
                else:
                    state.waiting.held[node_id] = ready
                if state.shown and not state.waiting.loading(self.service.nodes):
                    asyncio.get_running_loop().call_soon(self._advance, session_id)
                return True
        return False

    def _advance_when_held(self, session_id: str) -> None:
        """The step before is shown: the step waiting goes in once every node sent it has answered
        (its first frame is then split among them all), at most :data:`LOAD_AHEAD_WAIT_S` later."""
        state = self._sessions.get(session_id)
        if state is not None and state.waiting is not None and state.waiting.loading(self.service.nodes):
            asyncio.get_running_loop().call_later(LOAD_AHEAD_WAIT_S, self._advance, session_id, state.waiting)
            return
        self._advance(session_id)

    def _load_ahead(self, session: Session, step: MeshStep) -> None:
        """Every node loads ``step`` now, beside the step shown, which is drawn once more at most."""
        self.service.scheduler.rest(session.id)
        if self.service.settings.mode not in WHOLE_SCENE_MODES:
            return
        for node_id, link in self.service.nodes.items():
            step.sent.add(node_id)
            link.send_bytes(step.data)
            link.send(self.service.load_message(step.spec))

    def _advance(self, session_id: str, step: MeshStep | None = None) -> None:
        """Switch the session to its step waiting (if ``step`` is given: if it is that one), and
        answer that step's requests."""
        state = self._sessions.get(session_id)
        if state is None or state.waiting is None or state.answer is None or step not in (None, state.waiting):
            return
        step, answer = state.waiting, state.answer
        state.waiting = state.answer = None
        session = self.service.sessions.get(session_id)
        if session is None:
            answer.set_exception(SessionGone("the session was closed"))
            return
        first = self._switch(session, state, step)
        if not answer.done():
            answer.set_result(first)

    def _switch(self, session: Session, state: SessionMeshes, step: MeshStep) -> int:
        state.step, state.shown = step, False
        held = {n: ready for n, ready in step.held.items() if n in self.service.nodes}
        state.first = self.service.switch_scene(session, MESH_NAME, step.spec, None, held=held, keep_partition=True)
        self.service.scheduler.load_now(session.id)   # from memory: every other node at once
        self.service.apply()
        return state.first

    def _forget_gone(self) -> None:
        """Drop what is kept of sessions closed since (their requests waiting answer SessionGone)."""
        for session_id in [i for i in self._sessions if i not in self.service.sessions]:
            state = self._sessions.pop(session_id)
            if state.answer is not None and not state.answer.done():
                state.answer.set_exception(SessionGone("the session was closed"))
