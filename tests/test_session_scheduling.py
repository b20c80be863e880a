"""Several sessions over the shared nodes (issue 19): each session's frames have its own size,
scene and camera, a node draws only sessions whose scene it holds, and node time is shared
fairly among sessions with work (on a virtual clock: nodes answer after a modelled cost)."""

from __future__ import annotations

import heapq
import itertools
from collections import deque

import pytest

from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera
from tessera.scene.graph import ObjectGraph, SceneObject
from tessera.scene.state import ObjectPatch
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.actions import CancelFrames, LoadScene, PublishFrame, RenderTiles
from tessera.scheduling.dispatch import FIRST_FRAME_PIECES
from tessera.scheduling.fair_share import FIRST_FRAME_MS, FairShare
from tessera.scheduling.frame_jobs import DEFAULT_SESSION
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.codec import Codec
from tessera.wire.protocol import TileHeader
from tests.scheduling_support import answer

CONFIG = SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=0, still_codec=None)


def camera(i: int = 0) -> Camera:
    return Camera(eye=(0.0, 0.0, 5.0 + i), target=(0.0, 0.0, 0.0))


def cluster(nodes: int, sessions: dict[str, tuple[int, int]]) -> FrameScheduler:
    """``nodes`` nodes holding the default scene and every session of ``sessions`` (id → size)."""
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    for session_id, size in sessions.items():
        s.add_session(session_id, SchedulerConfig(size=size, max_fps=1e6, settle_frames=0, still_codec=None),
                      StaticBalancer(), f"builtin:{session_id}", 0.0)
    for node_id in range(1, nodes + 1):
        s.add_node(node_id, 0.0)
        for session_id in s.sessions:
            s.node_ready(node_id, 0.0, session_id=session_id)
    s.drain()
    return s


def test_a_new_session_has_every_node_load_its_scene_and_a_node_joining_loads_every_scene():
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_node(1, 0.0)
    assert s.drain() == [LoadScene(1, None, "builtin:spheres")]
    s.add_session("b", CONFIG, StaticBalancer(), "builtin:cluster", 0.0)
    assert s.drain() == [LoadScene(1, None, "builtin:cluster")]
    s.node_ready(1, 0.5)
    s.node_ready(1, 0.5, session_id="b")
    s.drain()
    s.add_node(2, 1.0)   # the coordinator's own scene once the session's is loaded (issue 31)
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(2, None, "builtin:cluster")]
    s.node_ready(2, 1.5, session_id="b")
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(2, None, "builtin:spheres")]
    with pytest.raises(ValueError, match="exists already"):
        s.add_session("b", CONFIG, StaticBalancer(), None, 0.0)


def test_nodes_joining_while_one_loads_a_sessions_scene_load_it_after_it_one_by_one():
    """The coordinator's own scene is loaded by no node while a session's scene loads before its
    first frame (issue 31: every node reading the built-in scene took the first node's cores)."""
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_session("big", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    s.add_node(1, 0.0)   # the session's scene first, the coordinator's own after it
    assert s.drain() == [LoadScene(1, None, "library/scan.ply")]
    s.add_node(2, 0.1)
    s.add_node(3, 0.2)
    assert s.drain() == [], "they wait while node 1 loads (on shared cores it is ready sooner alone)"
    s.node_ready(1, 1.0, session_id="big")
    assert {a for a in s.drain() if isinstance(a, LoadScene)} == {LoadScene(2, None, "library/scan.ply"),
                                                                  LoadScene(1, None, "builtin:spheres")}
    s.node_ready(1, 2.0)
    assert not [a for a in s.drain() if isinstance(a, LoadScene)], "node 2 loads the session's scene first"
    s.remove_node(2, 3.0)                                              # it was loading: the next one loads
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(3, None, "library/scan.ply")]
    s.node_ready(3, 4.0, session_id="big")
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(3, None, "builtin:spheres")]


def test_a_new_sessions_scene_is_loaded_by_one_node_after_the_other_fastest_first():
    s = cluster(3, {})
    s.set_speed(2, 2.0)
    s.add_session("big", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    assert s.drain() == [LoadScene(2, None, "library/scan.ply")]      # the others keep rendering
    s.node_ready(2, 1.0, session_id="big")
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(1, None, "library/scan.ply")]
    s.scene_failed(1, "big")                                           # node 1 could not: node 3 tries
    assert s.drain() == [LoadScene(3, None, "library/scan.ply")]
    s.add_session("other", CONFIG, StaticBalancer(), "library/other.ply", 2.0)
    assert s.drain() == [LoadScene(2, None, "library/other.ply")]
    s.remove_node(2, 3.0)                                              # it was loading: the next one loads
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(1, None, "library/other.ply")]
    s.remove_node(3, 4.0)
    assert not [a for a in s.drain() if isinstance(a, LoadScene)] and s.sessions["big"].loads_waiting == []


def test_nodes_of_other_machines_load_a_new_sessions_scene_at_once_and_one_by_one_on_each():
    """Nodes 1 and 2 share machine a, 3 is on b, 4 said no machine: one node of each machine loads
    the scene at once (b's share no cores with a's); a's second node after a's first. A node of a
    machine whose first node draws a big scene's first frame alone waits for that frame; the other
    machine's do not."""
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    for node_id, host in ((1, "a"), (2, "a"), (3, "b"), (4, "")):
        s.add_node(node_id, 0.0, host=host)
        s.node_ready(node_id, 0.0)
    s.drain()
    s.add_session("big", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    assert set(s.drain()) == {LoadScene(1, None, "library/scan.ply"), LoadScene(3, None, "library/scan.ply"),
                              LoadScene(4, None, "library/scan.ply")}
    s.node_ready(3, 1.0, session_id="big")
    assert not [a for a in s.drain() if isinstance(a, LoadScene)], "machine a still loads"
    s.node_ready(1, 1.5, session_id="big")
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(2, None, "library/scan.ply")]

    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    s.set_camera(camera(), 0.0, session_id="p")
    for node_id, host in ((1, "a"), (2, "a"), (3, "b"), (4, "b")):
        s.add_node(node_id, 0.0, host=host)
    assert {a for a in s.drain() if isinstance(a, LoadScene) and a.scene == "library/scan.ply"} == {
        LoadScene(1, None, "library/scan.ply"), LoadScene(3, None, "library/scan.ply")}
    s.node_holds(1, 24_769_300)
    s.node_ready(1, 1.0, session_id="p")
    assert not [a for a in s.drain() if isinstance(a, LoadScene) and a.scene == "library/scan.ply"]
    s.node_holds(3, 990_000)    # b's first node holds a small scene: b's next loads at once
    s.node_ready(3, 1.1, session_id="p")
    assert [a for a in s.drain() if isinstance(a, LoadScene) and a.scene == "library/scan.ply"] == [
        LoadScene(4, None, "library/scan.ply")]


def test_each_sessions_frames_have_its_size_scene_and_camera_and_only_nodes_holding_its_scene():
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_session("b", SchedulerConfig(size=(40, 30), max_fps=1e6, settle_frames=0, still_codec=None),
                  StaticBalancer(), "builtin:cluster", 0.0)
    for node_id in (1, 2):
        s.add_node(node_id, 0.0)
        s.node_ready(node_id, 0.0)
    s.node_ready(2, 0.0, session_id="b")
    s.drain()
    s.set_camera(camera(2), 0.0, session_id="b")
    s.set_camera(camera(1), 0.0)
    renders, published, now = [a for a in s.drain() if isinstance(a, RenderTiles)], [], 0.0
    while renders:
        now += 0.01
        actions = answer(s, renders.pop(0), now)
        renders += [a for a in actions if isinstance(a, RenderTiles)]
        published += [a.job for a in actions if isinstance(a, PublishFrame)]
        for action in (a for a in actions if isinstance(a, RenderTiles)):
            b = action.message.scene == "builtin:cluster"
            assert (action.message.size, action.message.camera) == (((40, 30), camera(2)) if b else
                                                                    ((64, 32), camera(1)))
            assert action.node_id == 2 or not b, "only node 2 holds b's scene"
    assert sorted((job.session, job.size, job.scene) for job in published) == [
        ("b", (40, 30), "builtin:cluster"), (DEFAULT_SESSION, (64, 32), "builtin:spheres")]


def test_a_change_in_one_session_never_drops_the_frames_of_another_and_closing_a_session_drops_its_own():
    s = cluster(4, {"b": (64, 32)})
    s.set_camera(camera(1), 0.0)
    renders = [a for a in s.drain() if isinstance(a, RenderTiles)]
    answer(s, renders[0], 0.01)             # one node free: b's frame starts, queued behind the default's
    s.set_camera(camera(2), 0.01, session_id="b")
    frame_of = {job.session: job.frame_id for job in s.in_flight.values()}
    assert set(frame_of) == {DEFAULT_SESSION, "b"}
    s.set_camera(camera(3), 0.02)           # the default session moves again
    assert frame_of["b"] in s.in_flight
    s.drain()
    s.remove_session("b", 0.03)
    actions = s.drain()
    assert frame_of["b"] not in s.in_flight and "b" not in s.sessions
    assert {a.frames for a in actions if isinstance(a, CancelFrames)} == {(frame_of["b"],)}


def test_resizing_a_session_drops_its_frames_and_renders_the_new_size():
    s = cluster(2, {})
    s.set_camera(camera(), 0.0)
    s.drain()
    first = s.resize((32, 16), 0.1)
    renders = [a for a in s.drain() if isinstance(a, RenderTiles)]
    assert renders and all(a.message.size == (32, 16) and a.message.frame >= first for a in renders)
    assert all(job.size == (32, 16) for job in s.in_flight.values())


def run_virtual(s: FrameScheduler, cost_ms: dict[str, float], seconds: float,
                wants: dict[str, float] | None = None, latency_s: float = 0.0,
                gaps_after_s: float = 0.0) -> dict[str, dict[str, float]]:
    """Every session moves its camera whenever a frame of it is published (or, for sessions in
    ``wants``, at that many frames per second); a node works through its queue in order, a tile
    costing its session's ``cost_ms`` × its share of the frame's pixels; messages each way take
    ``latency_s``; the scheduler is ticked at its deadlines. Returns per session its node busy
    ms, frames published and frames asked for, ``latency_ms``, its mean input → frame time, and
    ``longest_gap_s`` between its frames published from ``gaps_after_s`` on."""
    queue: dict[int, deque[tuple[RenderTiles, int]]] = {n: deque() for n in s.nodes}
    busy_until = dict.fromkeys(s.nodes, 0.0)
    events: list[tuple[float, int, str, object]] = []
    counter = 0
    figures = {sid: {"busy_ms": 0.0, "published": 0, "asked": 0} for sid in s.sessions}
    published_at: dict[str, list[float]] = {sid: [] for sid in s.sessions}
    ticks: set[float] = set()

    def push(at: float, kind: str, what: object) -> None:
        nonlocal counter
        counter += 1
        heapq.heappush(events, (at, counter, kind, what))

    def carry_out(actions: list, now: float) -> None:
        for action in actions:
            if isinstance(action, RenderTiles | CancelFrames):
                push(now + latency_s, "message", action)
            elif isinstance(action, PublishFrame):
                figures[action.job.session]["published"] += 1
                published_at[action.job.session].append(now)
                if wants is None or action.job.session not in wants:
                    ask(action.job.session, now)
        if (deadline := s.next_deadline(now)) is not None and max(deadline, now) not in ticks:
            ticks.add(max(deadline, now))
            push(max(deadline, now), "tick", None)

    def ask(session_id: str, now: float) -> None:
        figures[session_id]["asked"] += 1
        s.set_camera(camera(int(figures[session_id]["asked"]) % 7), now, session_id=session_id)
        carry_out(s.drain(), now)

    def start(node_id: int, now: float) -> None:
        if busy_until[node_id] > now or not queue[node_id]:
            return
        action, tile_id = queue[node_id].popleft()
        job = s.in_flight.get(action.message.frame)
        session_id = job.session if job else DEFAULT_SESSION
        rect = next(t.rect for t in action.message.tiles if t.tile == tile_id)
        size = action.message.size
        ms = cost_ms[session_id] * rect.area / (size[0] * size[1]) if job else 0.0
        figures[session_id]["busy_ms"] += ms
        busy_until[node_id] = now + ms / 1000.0
        push(busy_until[node_id], "done", (node_id, action, tile_id, ms))

    for session_id in s.sessions:
        if wants is None or session_id not in wants:
            ask(session_id, 0.0)
        else:
            for k in range(int(seconds * wants[session_id])):
                push(k / wants[session_id], "ask", session_id)
    while events and events[0][0] < seconds:
        now, _, kind, what = heapq.heappop(events)
        if kind == "ask":
            ask(what, now)
        elif kind == "tick":
            ticks.discard(now)
            s.tick(now)
            if (actions := s.drain()) or s.next_deadline(now) != now:
                carry_out(actions, now)
        elif kind == "message" and isinstance(what, CancelFrames):
            queue[what.node_id] = deque(q for q in queue[what.node_id] if q[0].message.frame not in what.frames)
        elif kind == "message":
            queue[what.node_id].extend((what, tile.tile) for tile in what.message.tiles)
            start(what.node_id, now)
        elif kind == "done":
            push(now + latency_s, "tile", what)
            start(what[0], now)
        else:
            node_id, action, tile_id, ms = what
            rect = next(t.rect for t in action.message.tiles if t.tile == tile_id)
            header = TileHeader(action.message.frame, tile_id, rect, Codec.JPEG, ms, 0.0, 0.0)
            if s.tile_arrived(node_id, header, b"", now) is not None:
                s.tile_sent(node_id, action.message.frame, tile_id, 0.0)
            carry_out(s.drain(), now)
    for session_id, session in s.sessions.items():
        figures[session_id]["latency_ms"] = session.stats.latency_ms
        times = [t for t in published_at[session_id] if t >= gaps_after_s]
        figures[session_id]["longest_gap_s"] = max((b - a for a, b in itertools.pairwise(times)), default=0.0)
    return figures


def jain(values: list[float]) -> float:
    return sum(values) ** 2 / (len(values) * sum(v * v for v in values))


def test_four_sessions_that_each_fill_the_cluster_get_equal_node_time():
    s = cluster(3, {"b": (64, 32), "c": (64, 32), "d": (64, 32)})
    costs = {DEFAULT_SESSION: 30.0, "b": 30.0, "c": 90.0, "d": 60.0}   # unequal frames, equal shares
    figures = run_virtual(s, costs, seconds=20.0)
    busy = [f["busy_ms"] for f in figures.values()]
    assert jain(busy) >= 0.95, figures
    assert figures["b"]["published"] > 2 * figures["c"]["published"], "cheap frames: more of them in the same time"
    assert sum(busy) / (3 * 20.0 * 1000.0) >= 0.85, "the nodes stay busy while work waits"


def test_with_message_latency_nodes_stay_busy_and_each_session_sees_its_input_within_two_frames():
    """Four sessions moving at 60 Hz, 5 ms each way: a node given work only once idle would sit out
    10 ms per tile (busy 0.67 here); dispatched ahead, it stays busy, and each session's latency
    stays under two of its own frame intervals."""
    s = cluster(3, {"b": (64, 32), "c": (64, 32), "d": (64, 32)})
    costs = {DEFAULT_SESSION: 60.0, "b": 30.0, "c": 90.0, "d": 60.0}
    seconds = 20.0
    figures = run_virtual(s, costs, seconds, wants=dict.fromkeys(costs, 60.0), latency_s=0.005)
    busy = [f["busy_ms"] for f in figures.values()]
    assert sum(busy) / (3 * seconds * 1000.0) >= 0.85, figures
    assert jain(busy) >= 0.95, figures
    for session_id, f in figures.items():
        frame_interval_ms = 1000.0 * seconds / f["published"]
        assert f["latency_ms"] <= 2 * frame_interval_ms, (session_id, f)


def test_a_frame_goes_ahead_to_a_node_ending_its_last_tile_and_a_newer_input_keeps_it():
    s = cluster(1, {"b": (64, 32)})
    s.set_camera(camera(1), 0.0)
    (first,) = [a for a in s.drain() if isinstance(a, RenderTiles)]
    answer(s, first, 0.030)                      # 30 ms round trip + busy 1 ms: the node's lead and rate
    s.drain()
    s.set_camera(camera(2), 0.030)
    (second,) = [a for a in s.drain() if isinstance(a, RenderTiles)]
    node = s.nodes[1]
    assert node.lead_s == pytest.approx(0.029) and node.ms_per_px is not None
    s.set_camera(camera(3), 0.031)               # the default session has a frame in flight: not ahead
    s.set_camera(camera(1), 0.031, session_id="b")
    ahead_at = s.next_deadline(0.031)
    assert ahead_at is not None and ahead_at < 0.030 + 0.001 + 1e-9, "its 1 ms tile ends within the 29 ms lead"
    s.tick(max(ahead_at, 0.031))
    (ahead,) = [a for a in s.drain() if isinstance(a, RenderTiles)]
    job = s.in_flight[ahead.message.frame]
    assert job.session == "b" and job.ahead and len(node.outstanding) == 2
    s.set_camera(camera(2), 0.032, session_id="b")
    assert ahead.message.frame in s.in_flight, "a frame sent ahead is begun: a newer input does not drop it"
    assert second.message.frame in s.in_flight


def test_a_light_session_gets_every_frame_it_asks_for_while_heavy_ones_share_the_rest():
    s = cluster(3, {"b": (64, 32), "light": (64, 32)})
    costs = {DEFAULT_SESSION: 60.0, "b": 60.0, "light": 15.0}
    figures = run_virtual(s, costs, seconds=20.0, wants={"light": 10.0})
    light = figures["light"]
    assert light["published"] >= light["asked"] - 1, figures
    heavy = [figures[DEFAULT_SESSION]["busy_ms"], figures["b"]["busy_ms"]]
    assert jain(heavy) >= 0.95 and min(heavy) > 4 * light["busy_ms"], figures


def test_a_node_is_sent_a_sessions_state_whole_when_another_sessions_frame_came_between():
    """A node keeps one scene state: a delta is sent only on the state it last got, of the same session."""
    s = cluster(1, {"b": (64, 32)})
    pending = []
    for session_id in s.sessions:
        s.set_scene(SceneTimeline(ObjectGraph([SceneObject("car")])), 0.0, session_id=session_id)
        s.set_camera(camera(), 0.0, session_id=session_id)
        pending += s.drain()
    while renders := [a for a in pending if isinstance(a, RenderTiles)]:
        pending = answer(s, renders[0], 0.5) + [a for a in pending if a is not renders[0]]
    kinds = []
    for now, session_id in enumerate(["default", "default", "b", "default"], start=1):
        s.set_objects({"car": ObjectPatch.from_json({"translation": [now, 0, 0]}, "car")}, float(now), session_id)
        renders = [a for a in s.drain() if isinstance(a, RenderTiles)]
        assert len(renders) == 1
        kinds.append(type(renders[0].message.state).__name__)
        answer(s, renders[0], now + 0.5)
    assert kinds == ["SceneState", "StateDelta", "SceneState", "SceneState"]


def test_a_session_only_a_busy_node_holds_starts_when_another_node_is_free():
    """Node 1 alone holds session p's scene and is never idle (session a's frames keep a tile
    queued there): p's frame starts once node 2 is free, its tile queued at node 1."""
    s = cluster(2, {"a": (64, 32)})
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    s.node_ready(1, 0.0, session_id="p")
    s.drain()
    s.set_camera(camera(), 0.0, session_id="a")
    first = {a.node_id: a for a in s.drain() if isinstance(a, RenderTiles)}
    assert sorted(first) == [1, 2]
    answer(s, first[2], 0.01)   # node 2 is free, node 1 still on a's tile
    s.set_camera(camera(), 0.02, session_id="p")
    started = [a for a in s.drain() if isinstance(a, RenderTiles)]
    assert [(a.node_id, s.in_flight[a.message.frame].session) for a in started] == [(1, "p")]
    assert s.nodes[1].outstanding and len(s.nodes[1].outstanding) == 2, "queued behind a's tile"
    actions = answer(s, first[1], 0.05)
    pending = started[0]   # p's first frame goes in pieces, one at a time, while node 1 alone holds it
    while pending is not None:
        actions += (more := answer(s, pending, 0.08))
        pending = next((a for a in more if isinstance(a, RenderTiles)), None)
    assert [a.job.session for a in actions if isinstance(a, PublishFrame)] == ["a", "p"]


def test_a_session_few_nodes_hold_draws_its_frames_in_pieces_one_at_a_time():
    """Node 1 alone holds p's scene. Alone, p's frame goes whole; beside session a's frame, p's
    first frame (its cost unknown) goes in FIRST_FRAME_PIECES pieces, the next sent to node 1 when
    the one before came back, so a's tile queued there comes first; once a frame of p took 200 ms,
    its frames go in pieces of about PIECE_MS (40 ms)."""
    s = cluster(2, {"a": (64, 32)})
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    s.node_ready(1, 0.0, session_id="p")
    s.drain()
    assert s._pieces(s.sessions["p"], 1, 2.0, 0.0) == 1, "no other session draws: nothing to wait for p"
    s.set_camera(camera(), 0.0, session_id="a")
    queued = {a.node_id: a for a in s.drain() if isinstance(a, RenderTiles)}
    actions = answer(s, queued[2], 0.005)   # node 2 is free, node 1 still on a's tile
    s.set_camera(camera(), 0.01, session_id="p")
    (pending,) = [a for a in s.drain() if isinstance(a, RenderTiles)]
    job = s.in_flight[pending.message.frame]
    assert job.one_by_one and len(job.tiles) == FIRST_FRAME_PIECES and len(pending.message.tiles) == 1
    actions, pieces = actions + answer(s, queued[1], 0.03), 0
    while pending is not None:
        assert [key for key in s.nodes[1].outstanding if key[0] == job.frame_id] == [
            (job.frame_id, pending.message.tiles[0].tile)], "one piece at a time"
        actions += (more := answer(s, pending, 0.05 + 0.01 * pieces))
        pending, pieces = next((a for a in more if isinstance(a, RenderTiles)), None), pieces + 1
    assert pieces == FIRST_FRAME_PIECES
    assert [a.job.session for a in actions if isinstance(a, PublishFrame)] == ["a", "p"]
    s.fair.finished("p", 0.0, 200.0, 0.2)
    assert s._pieces(s.sessions["p"], 1, 2.0, 0.2) == 5, "200 ms of node time / 40"
    assert s._pieces(s.sessions["p"], 1, 2.0, 0.71) == 1, "a had nothing to do for over half a second"


def test_a_session_few_nodes_hold_pays_for_holding_them_up():
    """Session p's scene is on node 1 alone (the others still load it) and its frame costs 150 ms
    there; three sessions of 30 ms frames over all three nodes move too. p's node time counts three
    times (three nodes ready, one holds it): it takes about a fair share of node 1 (a quarter), not
    a fair share of the whole cluster on node 1, where the others' tiles wait behind its frames
    (unscaled: p took 51 % of node 1, the others a third fewer frames)."""
    s = cluster(3, {"b": (64, 32), "c": (64, 32)})
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
    s.node_ready(1, 0.0, session_id="p")
    s.drain()
    costs = {DEFAULT_SESSION: 30.0, "b": 30.0, "c": 30.0, "p": 150.0}
    figures = run_virtual(s, costs, seconds=20.0, gaps_after_s=1.0)
    assert 0.2 * 20_000.0 <= figures["p"]["busy_ms"] <= 0.3 * 20_000.0, figures
    others = [figures[sid]["busy_ms"] for sid in (DEFAULT_SESSION, "b", "c")]
    assert jain(others) >= 0.95 and min(others) > 2.5 * figures["p"]["busy_ms"], figures
    assert max(figures[sid]["longest_gap_s"] for sid in (DEFAULT_SESSION, "b", "c")) < 0.1, (
        "p's frames in pieces: the others wait for a piece at node 1, not a frame (whole: 0.18 s)", figures)


def test_a_new_sessions_first_frame_is_charged_as_the_costliest_others_frame():
    """Charged 10 ms, a session whose first frame takes long stays the least served while it is
    drawn, and the others, more than a frame ahead of it, wait with nodes free."""
    fair = FairShare()
    fair.add("a")
    assert fair.started("a") == FIRST_FRAME_MS, "the first session: nothing measured yet"
    fair.finished("a", FIRST_FRAME_MS, 90.0, 1.0)
    fair.add("p")
    assert fair.started("p", scarcity=3.0) == pytest.approx(270.0)
    assert fair.frame_cost("p") is None and fair.frame_cost("a") == 90.0


def test_a_session_switching_scene_does_not_hold_the_coordinators_own_scene_back():
    """A simulation's session switches scene at every mesh step, each awaiting its first frame: a
    node joining meanwhile still loads the coordinator's own scene."""
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_session("sim", CONFIG, StaticBalancer(), "mesh:sim/1", 0.0)
    s.add_node(1, 0.0)
    s.node_ready(1, 0.5, session_id="sim")
    s.node_ready(1, 0.5)
    s.drain()
    s.replace_session("sim", CONFIG, StaticBalancer(), "mesh:sim/2", 1.0)
    s.load_now("sim")
    assert s.sessions["sim"].awaits_first_frame
    s.drain()
    s.add_node(2, 1.1)
    assert LoadScene(2, None, "builtin:spheres") in s.drain()
