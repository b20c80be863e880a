"""The scheduler and the scene state (issue 11) on a virtual clock: a frame is bound to one state
version when it starts; render messages bring each node to it (whole at first, then deltas); a
tile showing another state is refused; poses and animation changes start frames on demand, a
playing animation keeps them coming, a pause ends with the still frame."""

from __future__ import annotations

import numpy as np
import pytest

from tessera.balancers.static import StaticBalancer
from tessera.scene.animation import Animation, Channel, Sampler
from tessera.scene.graph import ObjectGraph, SceneObject
from tessera.scene.state import HISTORY, ObjectPatch, SceneState, SceneStateError, StateDelta, UnknownObjectError
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.actions import LoadScene, PublishFrame, RenderTiles
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.codec import Codec
from tessera.wire.protocol import ProtocolError, TileHeader
from tests.test_scheduler import camera

SIZE = (64, 32)


def scene_scheduler(nodes: int = 2, **config) -> FrameScheduler:
    """Ready nodes 1…N, a scene (``car`` drives x 0 → 10 over [0, 2] s; ``tree``) and a camera:
    frame 1 is on its way."""
    config.setdefault("max_fps", 1e6)
    config.setdefault("settle_frames", 0)
    s = FrameScheduler(SchedulerConfig(size=SIZE, **config), StaticBalancer())
    for node_id in range(1, nodes + 1):
        s.add_node(node_id, 0.0)
        assert s.drain() == [LoadScene(node_id)], "a node that joins is told to load the whole scene"
        s.node_ready(node_id, 0.0)
    graph = ObjectGraph([SceneObject("car"), SceneObject("tree")])
    drive = Sampler(np.array([0.0, 2.0]), np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]), "LINEAR")
    s.set_scene(SceneTimeline(graph, [Animation("drive", (Channel("car", "translation", drive),))]), 0.0)
    s.set_camera(camera(), 0.0)
    return s


def finish(s: FrameScheduler, frame_id: int, now: float) -> list:
    """Every outstanding tile of ``frame_id`` comes back, rendered in the frame's state; returns the actions."""
    job = s.in_flight[frame_id]
    tag = 0 if job.state is None else job.state.version
    actions = []
    for node in list(s.nodes.values()):
        for f, t in [k for k in node.outstanding if k[0] == frame_id]:
            s.tile_arrived(node.node_id, TileHeader(f, t, job.tiles[t].rect, job.codec, 5.0, 1.0, 1.0, tag),
                           b"tile", now)
            s.tile_sent(node.node_id, f, t, 0.5)
            actions += s.drain()
    return actions


def states(actions) -> dict[int, list[SceneState | StateDelta | None]]:
    """node → the state payloads of its render messages among ``actions``."""
    out: dict[int, list[SceneState | StateDelta | None]] = {}
    for a in actions:
        if isinstance(a, RenderTiles):
            out.setdefault(a.node_id, []).append(a.message.state)
    return out


def frames(actions) -> list[int]:
    return sorted({a.message.frame for a in actions if isinstance(a, RenderTiles)})


def published(actions) -> list:
    return [a.job for a in actions if isinstance(a, PublishFrame)]


def test_the_first_render_message_carries_the_whole_state_then_deltas():
    s = scene_scheduler()
    first = s.drain()
    job = s.in_flight[1]
    assert job.state is not None and job.state.version == 0
    assert all(payloads == [job.state] for payloads in states(first).values()), "whole, to both nodes"
    finish(s, 1, 0.1)
    s.set_objects({"car": ObjectPatch(translation=(1.0, 2.0, 3.0))}, 0.2)
    second = s.drain()
    job = s.in_flight[2]
    assert job.state is not None and job.state.version == 1
    for payloads in states(second).values():
        (delta,) = payloads
        assert isinstance(delta, StateDelta) and (delta.base, delta.version) == (0, 1)
        assert dict(delta.objects) == {"car": job.state.objects["car"]}


def test_a_node_that_joins_gets_the_whole_state():
    s = scene_scheduler(nodes=1)
    s.drain()
    finish(s, 1, 0.1)
    s.add_node(2, 0.2)
    s.node_ready(2, 0.2)
    payloads = states(s.drain())
    assert isinstance(payloads[1][0], StateDelta) and isinstance(payloads[2][0], SceneState)


def test_after_a_failed_tile_the_node_gets_the_whole_state():
    s = scene_scheduler(nodes=1)
    s.drain()
    s.tile_failed(1, 1, 0, 0.1)
    (payload,) = states(s.drain())[1]
    assert isinstance(payload, SceneState) and payload is s.in_flight[1].state


def test_a_version_the_log_no_longer_keeps_is_sent_whole():
    s = scene_scheduler(nodes=1)
    s.drain()
    finish(s, 1, 0.1)
    scene = s.default.scene
    assert scene is not None
    for step in range(HISTORY + 1):
        scene.set_objects({"tree": ObjectPatch(translation=(step + 1.0, 0.0, 0.0))})
        scene.bind(0.2)
    s.invalidate(0.2)
    (payload,) = states(s.drain())[1]
    assert isinstance(payload, SceneState) and payload.version == HISTORY + 1


def test_a_tile_of_another_state_is_refused():
    s = scene_scheduler(nodes=1)
    s.drain()
    job = s.in_flight[1]
    tile = job.tiles[0]
    with pytest.raises(ProtocolError, match="shows scene state 7, the frame's is 0"):
        s.tile_arrived(1, TileHeader(1, 0, tile.rect, job.codec, 1.0, 1.0, 1.0, state=7), b"tile", 0.1)


def test_a_frame_keeps_the_state_it_started_with():
    s = scene_scheduler(nodes=2, max_in_flight=2)
    s.drain()
    job = s.in_flight[1]
    tile = next(t for t in job.tiles if t.node_id == 1)
    s.tile_arrived(1, TileHeader(1, tile.tile_id, tile.rect, job.codec, 1.0, 1.0, 1.0, state=0), b"tile", 0.05)
    frame = s.set_objects({"car": ObjectPatch(visible=False)}, 0.1)
    assert frame == 2
    s.drain()
    assert s.in_flight[1].state is job.state and job.state is not None and job.state.objects["car"].visible
    later = s.in_flight[2].state
    assert later is not None and not later.objects["car"].visible and later.version == job.state.version + 1


def test_an_unknown_object_or_bad_value_changes_nothing():
    s = scene_scheduler(nodes=1)
    s.drain()
    finish(s, 1, 0.1)
    s.tick(1.0)
    s.drain()
    before = s.next_frame_id
    with pytest.raises(UnknownObjectError):
        s.set_objects({"bus": ObjectPatch(visible=False)}, 1.0)
    with pytest.raises(SceneStateError):
        s.set_animation(1.0, speed=float("nan"))
    scene = s.default.scene
    assert s.next_frame_id == before and s.drain() == [] and scene is not None and scene.overrides == {}


def test_a_playing_animation_keeps_frames_coming_and_a_pause_ends_with_the_still_frame():
    s = scene_scheduler(nodes=1, max_fps=10.0, still_delay_ms=200)
    s.drain()
    finish(s, 1, 0.01)
    s.tick(0.5)
    (still,) = frames(s.drain())
    assert s.in_flight[still].still, "the still frame of the paused scene"
    assert published(finish(s, still, 0.55))[0].still
    assert s.default.settled and s.next_deadline(0.6) is None
    first = s.set_animation(1.0, playing=True)
    times = []
    now = 1.0
    for _ in range(6):
        s.tick(now)
        started = frames(s.drain())
        if started:
            (frame_id,) = started
            times.append(s.in_flight[frame_id].state.time)
            finish(s, frame_id, now + 0.01)
            s.drain()
        deadline = s.next_deadline(now + 0.01)
        assert deadline is not None, "playing: another frame is always owed"
        now = max(deadline, now + 0.01)
    assert first == 3 and len(times) == 6, times
    assert times == sorted(times) and times[0] == 0.0 and times[-1] == pytest.approx(0.5, abs=0.02)
    assert not s.default.settled
    s.set_animation(now, playing=False)
    s.tick(now)
    (paused,) = frames(s.drain())
    paused_state = s.in_flight[paused].state
    assert not s.in_flight[paused].still and paused_state is not None
    finish(s, paused, now + 0.01)
    s.tick(now + 0.5)
    (still_id,) = frames(s.drain())
    still = s.in_flight[still_id]
    assert still.still and still.codec is Codec.PNG and still.state is paused_state, "the same state, lossless"
    finish(s, still_id, now + 0.6)
    assert s.default.settled and s.next_deadline(now + 1.0) is None


def test_a_failed_tile_of_a_dropped_frame_also_gets_the_node_the_whole_state():
    s = scene_scheduler(nodes=1, still_delay_ms=200)
    s.drain()
    finish(s, 1, 0.01)
    s.tick(0.5)
    (still,) = frames(s.drain())
    s.set_objects({"tree": ObjectPatch(visible=False)}, 0.6)
    (next_frame,) = frames(s.drain())
    assert still not in s.in_flight, "the still frame was dropped"
    s.tile_failed(1, still, 0, 0.7)
    s.set_objects({"tree": ObjectPatch(visible=True)}, 0.7)
    (payload,) = states(finish(s, next_frame, 0.75))[1]
    assert isinstance(payload, SceneState), "its replica may be what failed"
