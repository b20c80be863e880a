"""Picking without GL (issue 35): the pixel's ray and window, the cap's entry, the nearest of
several answers, the ``pick`` messages, the node protocol handing picks out ahead of queued
tiles, and the coordinator's desk of picks waiting for their nodes."""

from __future__ import annotations

import asyncio
import json
import math

import numpy as np
import pytest

from node.protocol import Draw, PickPixel, Send
from server.picking import PickDesk
from tessera.geometry import Camera, Rect, view_projection
from tessera.scene.state import ObjectState, SceneState, StateDelta
from tessera.tools.picking import PickHit, cap_entry, nearest, pixel_ray, triangle_hit, window_matrix
from tessera.wire.messages import InvalidMessage, parse
from tessera.wire.pick_messages import FROM_NODE_PICKS, TO_NODE_PICKS, Pick, PickResult
from tests.test_node_protocol import CAMERA, connected, render

SIZE = (640, 360)
BOUNDS = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def test_the_pixel_window_and_ray_meet_at_the_pixel_centre() -> None:
    camera = Camera(eye=(1.0, 2.0, 5.0), target=(0.0, 0.0, 0.0))
    for x, y in [(0, 0), (17, 300), (639, 359), (320, 180)]:
        origin, direction = pixel_ray(camera, SIZE, BOUNDS, x, y)
        assert math.isclose(np.linalg.norm(direction), 1.0)
        clip = window_matrix(Rect(x, y, 1, 1), SIZE) @ view_projection(camera, SIZE, BOUNDS) @ np.append(
            origin + 4.0 * direction, 1.0)
        assert np.allclose(clip[:2] / clip[3], 0.0, atol=1e-9), "the ray goes through the 1x1 window's centre"
    assert np.array_equal(window_matrix(Rect(0, 0, *SIZE), SIZE), np.identity(4))


def test_triangle_and_cap_hits() -> None:
    origin, direction = np.zeros(3), np.array([0.0, 0.0, -1.0])
    distance, normal = triangle_hit(origin, direction, np.array([[-1, -1, -3], [1, -1, -3], [0, 1, -3.0]]))
    assert distance == 3.0 and np.allclose(normal, [0, 0, 1]), "the normal faces the eye, whatever the winding"
    distance, normal = triangle_hit(origin, direction, np.array([[-1, -1, -3], [0, 1, -3], [1, -1, -3.0]]))
    assert distance == 3.0 and np.allclose(normal, [0, 0, 1])
    assert triangle_hit(origin, direction, np.array([[0, 0, -1], [0, 1, -2], [0, 2, -3.0]])) is None
    halfspaces = np.array([[0, 0, -1, -2.0], [1, 0, 0, 5.0]])     # keeps z <= -2 and x >= -5
    assert cap_entry(origin, direction, halfspaces) == (2.0, 0)
    assert cap_entry(np.array([0, 0, -2.5]), direction, halfspaces) is None, "the eye is inside what is kept"


def test_the_nearest_answer_wins() -> None:
    near = PickHit("a", 3, (0.0, 0.0, -1.0), (0.0, 0.0, 1.0), 1.0)
    far = PickHit("b", 7, (0.0, 0.0, -2.0), (0.0, 0.0, 1.0), 2.0)
    assert nearest([None, far, near]) == near and nearest([None, None]) is None


def test_pick_messages() -> None:
    state = SceneState(4, 0.0, {"car": ObjectState()})
    pick = Pick(id=9, camera=Camera.from_json(CAMERA), size=(64, 32), x=63, y=31, state=state, share=2)
    assert Pick.from_json(pick.to_json()).to_json() == pick.to_json() and "clip" not in pick.to_json()
    with pytest.raises(InvalidMessage, match="outside the 64x32 frame"):
        Pick.from_json({**pick.to_json(), "x": 64})
    with pytest.raises(InvalidMessage, match="a delta"):
        Pick.from_json({**pick.to_json(), "state": StateDelta(3, 4, 0.0).to_json()})
    result = PickResult(id=9, hit=True, object="car", primitive=0, point=(1.0, 2.0, 3.0), normal=(0.0, 1.0, 0.0),
                        depth=2.5)
    assert PickResult.from_json(result.to_json()) == result
    assert PickResult(id=9, hit=False).to_json() == {"type": "pick_result", "id": 9, "hit": False}
    with pytest.raises(InvalidMessage, match="names its object"):
        PickResult.from_json({"id": 1, "hit": True})
    for message, kinds in ((pick, TO_NODE_PICKS), (result, FROM_NODE_PICKS)):
        assert parse(message.to_text(), kinds).to_json() == message.to_json()


def test_a_pick_goes_ahead_of_the_tiles_queued_and_leaves_the_state_alone() -> None:
    state = SceneState(1, 0.0, {"car": ObjectState((1.0, 0.0, 0.0))})
    protocol = connected(render(5, tiles=3, state=state.to_json()))
    first = protocol.next_action()
    assert isinstance(first, Draw) and first.tile.tile == 0
    other = SceneState(9, 2.0, {"car": ObjectState((9.0, 0.0, 0.0))})
    pick = {"type": "pick", "id": 1, "camera": CAMERA, "size": [64, 32], "x": 3, "y": 4, "state": other.to_json()}
    protocol.receive_text(json.dumps(pick))
    second = protocol.next_action()
    assert isinstance(second, PickPixel) and second.request.id == 1
    third = protocol.next_action()
    assert isinstance(third, Draw) and third.tile.tile == 1 and third.state is not None
    assert third.state.objects["car"].translation == (1.0, 0.0, 0.0)
    protocol.receive_text(json.dumps({**pick, "id": 2, "x": 64}))
    refused = [protocol.next_action() for _ in range(2)]
    answer = next(a.message for a in refused if isinstance(a, Send))
    assert isinstance(answer, PickResult) and answer.id == 2 and not answer.hit and "outside" in (answer.error or "")


class FakeService:
    scheduler = None

    def __init__(self) -> None:
        self.sent: list[tuple[int, Pick]] = []
        self.gone: set[int] = set()

    def send_to(self, node_id: int, message) -> bool:
        self.sent.append((node_id, message))
        return node_id not in self.gone


def test_the_desk_matches_answers_to_their_node_and_request() -> None:
    async def scenario() -> None:
        service = FakeService()
        desk = PickDesk(service, timeout_s=0.2)   # type: ignore[arg-type]
        request = {"camera": Camera.from_json(CAMERA), "size": (64, 32), "x": 1, "y": 1}
        asked = asyncio.create_task(desk._ask(3, request))
        await asyncio.sleep(0)
        (node_id, pick), = service.sent
        assert node_id == 3
        desk.answered(4, PickResult(id=pick.id, hit=False))             # another node's answer: dropped
        desk.answered(3, PickResult(id=pick.id + 1, hit=False))         # another request's: dropped
        assert not asked.done()
        desk.answered(3, PickResult(id=pick.id, hit=False, error=None))
        assert (await asked).error is None
        left = asyncio.create_task(desk._ask(3, request))
        await asyncio.sleep(0)
        desk.node_left(3)
        assert (await left).error == "the node left"
        service.gone.add(5)
        assert (await desk._ask(5, request)).error == "the node left"
        assert "no answer within 0.2 s" in ((await desk._ask(6, request)).error or "")
        assert not desk._waiting

    asyncio.run(scenario())
