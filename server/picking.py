"""Picks on the coordinator (issue 35): ``GET /api/sessions/{id}/pick?x=&y=`` asks the nodes, which
answer with an id pass of that one pixel (:mod:`node.gl.id_pass`), ahead of the tiles they have
queued; nothing is drawn for picking otherwise.

In sort-first and the hybrid every node holds the whole scene: the pick goes to one node holding
the session's scene, the one that owes fewest tiles (another one if it fails or leaves). In
sort-last each node holds a share: the pick goes to every share of the newest data partition and
the nearest answer wins. The pick is of the session's newest camera and scene state and its clip.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

from server.sessions import Session
from tessera.decomposition.sort_last import SortLast
from tessera.scheduling.scheduler import FrameScheduler
from tessera.tools.picking import PickHit, nearest
from tessera.wire.messages import Message
from tessera.wire.pick_messages import Pick, PickResult

#: How long a pick waits for the nodes' answers (s).
PICK_TIMEOUT_S = 10.0


class PickFailed(RuntimeError):
    """No answer could be had: ``status`` is the HTTP status to give, with the reason."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


class NodeSender(Protocol):
    """What the desk needs of the service."""

    scheduler: FrameScheduler

    def send_to(self, node_id: int, message: Message) -> bool:
        """Send ``message`` to node ``node_id``; False when it is gone."""


@dataclass
class _Asked:
    node_id: int
    answer: asyncio.Future[PickResult] = field(default_factory=lambda: asyncio.get_running_loop().create_future())


class PickDesk:
    """The picks waiting for their nodes' answers, by request id."""

    def __init__(self, service: NodeSender, timeout_s: float = PICK_TIMEOUT_S) -> None:
        self.service, self.timeout_s = service, timeout_s
        self._ids = itertools.count(1)
        self._waiting: dict[int, _Asked] = {}

    async def pick(self, session: Session, x: int, y: int) -> dict[str, Any]:
        """What pixel (``x``, ``y``) of ``session``'s frame sees: ``{"hit": false}`` or the hit's
        JSON (:class:`PickHit`). PickFailed (409: nothing to pick yet, 503: no node could answer)."""
        frames = session.frames
        if frames.camera is None or session.bounds is None:
            raise PickFailed(409, "no node has loaded the scene yet")
        state = None if frames.scene is None else frames.scene.state_at(time.monotonic())
        request = dict(camera=frames.camera, size=frames.size, x=x, y=y, scene=frames.scene_key, state=state,
                       clip=frames.clip)
        scheduler = self.service.scheduler
        mode = frames.mode
        if isinstance(mode, SortLast):
            plan = mode.shares.plan
            if plan is None or not mode.shares.complete:
                raise PickFailed(503, "the nodes are loading a new data partition; try again")
            answers = await asyncio.gather(*(self._ask(node_id, {**request, "share": plan.version})
                                             for node_id in plan.holders))
            failed = [answer.error for answer in answers if answer.error is not None]
            if failed:
                raise PickFailed(503, f"a node could not pick: {failed[0]}")
            hit = nearest(_hit(answer) for answer in answers)
            return {"hit": False} if hit is None else hit.to_json()
        holders = sorted(scheduler.table.holding(frames.ready), key=lambda n: (len(n.outstanding), n.node_id))
        if not holders:
            raise PickFailed(503, "no node holds the session's scene yet")
        reason = ""
        for node in holders[:2]:   # another node when the first fails or leaves
            answer = await self._ask(node.node_id, request)
            if answer.error is None:
                hit = _hit(answer)
                return {"hit": False} if hit is None else hit.to_json()
            reason = answer.error
        raise PickFailed(503, f"no node could pick: {reason}")

    async def _ask(self, node_id: int, request: dict[str, Any]) -> PickResult:
        request_id = next(self._ids)
        asked = self._waiting[request_id] = _Asked(node_id)
        try:
            if not self.service.send_to(node_id, Pick(id=request_id, **request)):
                return PickResult(id=request_id, hit=False, error="the node left")
            return await asyncio.wait_for(asyncio.shield(asked.answer), self.timeout_s)
        except TimeoutError:
            return PickResult(id=request_id, hit=False, error=f"no answer within {self.timeout_s:g} s")
        finally:
            self._waiting.pop(request_id, None)

    def answered(self, node_id: int, result: PickResult) -> None:
        """A node's ``pick_result`` (one for a pick it was not asked, or asked of another node, is dropped)."""
        asked = self._waiting.get(result.id)
        if asked is not None and asked.node_id == node_id and not asked.answer.done():
            asked.answer.set_result(result)

    def node_left(self, node_id: int) -> None:
        """The node is gone: the picks it owed are answered with that."""
        for request_id, asked in self._waiting.items():
            if asked.node_id == node_id and not asked.answer.done():
                asked.answer.set_result(PickResult(id=request_id, hit=False, error="the node left"))


def _hit(answer: PickResult) -> PickHit | None:
    if not answer.hit:
        return None
    assert answer.object is not None and answer.primitive is not None and answer.point is not None
    assert answer.normal is not None and answer.depth is not None
    return PickHit(answer.object, answer.primitive, answer.point, answer.normal, answer.depth)
