"""A session's first frame goes first (issue 31: the first frame of a 24.8M-triangle model after a
restart): no settle frame beside a first frame cut into pieces, no still sample of another session
on the nodes while a session's scene loads and its first frame is drawn; nor between a simulation's
mesh steps, whose partition goes on from step to step (issue 33). Pure scheduler, no I/O."""

from __future__ import annotations

import json

from server.node_calibration import NodeCalibration
from server.nodes import NodeLink
from tessera.balancers import create_balancer
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera
from tessera.scheduling.actions import LoadScene, PublishFrame, RenderTiles
from tessera.scheduling.dispatch import FIRST_FRAME_PIECES
from tessera.scheduling.frame_jobs import DEFAULT_SESSION
from tessera.scheduling.job_scheduler import JobScheduler
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.protocol import TileHeader, state_tag
from tests.scheduling_support import answer

CONFIG = SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=0, still_codec=None)


def camera(i: int = 0) -> Camera:
    return Camera(eye=(0.0, 0.0, 5.0 + i), target=(0.0, 0.0, 0.0))


def renders(actions: list) -> list[RenderTiles]:
    return [a for a in actions if isinstance(a, RenderTiles)]


def test_a_first_frame_in_pieces_has_no_settle_frame_beside_it():
    """Node 1 alone holds p's scene while session a draws: p's first frame goes in pieces, and with
    settle frames on no second frame of p (the same picture again) starts until it is published."""
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_session("a", CONFIG, StaticBalancer(), "builtin:a", 0.0)
    s.add_session("p", SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=2, still_codec=None),
                  StaticBalancer(), "library/scan.ply", 0.0)
    for node_id in (1, 2):
        s.add_node(node_id, 0.0)
        s.node_ready(node_id, 0.0, session_id="a")
    s.node_ready(1, 0.0, session_id="p")
    s.drain()
    s.set_camera(camera(), 0.0, session_id="a")
    queued = {a.node_id: a for a in renders(s.drain())}
    actions = answer(s, queued[2], 0.005)
    s.set_camera(camera(), 0.01, session_id="p")
    (pending,) = renders(s.drain())
    assert s.in_flight[pending.message.frame].one_by_one
    actions += answer(s, queued[1], 0.03)
    pieces = 0
    while pending is not None:
        assert len(s.sessions["p"].frames) == 1, "no settle frame beside the pieces"
        more = answer(s, pending, 0.05 + 0.01 * pieces)
        actions += more
        pending = next((a for a in renders(more) if s.in_flight[a.message.frame].session == "p"
                        and s.in_flight[a.message.frame].one_by_one), None)
        pieces += 1
    assert pieces == FIRST_FRAME_PIECES
    assert "p" in [a.job.session for a in actions if isinstance(a, PublishFrame)]


def test_the_other_nodes_load_a_new_sessions_scene_once_its_first_frame_is_out():
    """After a restart node 1 holds the session's big scene (with its levels of detail or without)
    and draws its first frame whole; nodes 2 and 3, which joined meanwhile, are told to load it (one
    after the other) once that frame is published, not while it is drawn (their uploads took its
    cores); a node that leaves before it drew the frame hands the load on. A small scene's next
    node loads at once."""
    for levels in (True, False):
        s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
        s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
        s.set_camera(camera(), 0.0, session_id="p")
        for node_id in (1, 2, 3):
            s.add_node(node_id, 0.0)
        assert [a for a in s.drain() if isinstance(a, LoadScene) and a.scene == "library/scan.ply"] == [
            LoadScene(1, None, "library/scan.ply")]
        if levels:
            s.levels_ready(1, session_id="p")
        s.node_holds(1, 24_769_300)
        s.node_ready(1, 1.0, session_id="p")
        actions = s.drain()
        assert not [a for a in actions if isinstance(a, LoadScene) and a.scene == "library/scan.ply"]
        pending = renders(actions)
        published, now = [], 1.0
        while pending and not published:
            now += 0.01
            more = answer(s, pending.pop(0), now)
            published = [a for a in more if isinstance(a, PublishFrame) and a.job.session == "p"]
            if not published:
                assert not [a for a in more if isinstance(a, LoadScene) and a.scene == "library/scan.ply"]
            pending += renders(more)
        assert published and [a for a in more if isinstance(a, LoadScene) and a.scene == "library/scan.ply"] == [
            LoadScene(2, None, "library/scan.ply")]

    def first_node_ready(triangles: int) -> tuple[FrameScheduler, list]:
        s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
        s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.0)
        s.set_camera(camera(), 0.0, session_id="p")
        for node_id in (1, 2):
            s.add_node(node_id, 0.0)
        s.node_holds(1, triangles)
        s.node_ready(1, 1.0, session_id="p")
        return s, s.drain()

    s, actions = first_node_ready(24_769_300)
    assert LoadScene(2, None, "library/scan.ply") not in actions
    s.remove_node(1, 2.0)
    assert LoadScene(2, None, "library/scan.ply") in s.drain()
    assert LoadScene(2, None, "library/scan.ply") in first_node_ready(990_000)[1], "a small scene: at once"


def test_a_first_frame_in_pieces_is_shared_by_the_next_node_to_load_the_scene():
    """While another session keeps the nodes busy a first frame goes in pieces: the next node loads
    the scene at once and takes its share of them."""
    s = FrameScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_session("a", CONFIG, StaticBalancer(), "builtin:a", 0.0)
    for node_id in (1, 2):
        s.add_node(node_id, 0.0)
        s.node_ready(node_id, 0.0, session_id="a")
    s.drain()
    s.set_camera(camera(), 0.0, session_id="a")
    queued = {a.node_id: a for a in renders(s.drain())}
    answer(s, queued[2], 0.005)
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.01)
    s.set_camera(camera(), 0.01, session_id="p")
    assert [a for a in s.drain() if isinstance(a, LoadScene)] == [LoadScene(1, None, "library/scan.ply")]
    s.node_holds(1, 24_769_300)
    s.node_ready(1, 0.02, session_id="p")
    actions = s.drain()
    assert s.sessions["p"].pieces_in_flight
    assert LoadScene(2, None, "library/scan.ply") in actions


def test_no_still_sample_of_another_session_starts_while_a_session_awaits_its_first_frame():
    """The default session refines a still on node 1; session p's scene loads there: no sample
    starts (and no deadline asks for one) until p's first frame is published, then they go on."""
    config = SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=0, still_delay_ms=0.0, still_samples=8)
    s = FrameScheduler(config, StaticBalancer(), scene="builtin:spheres")
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    s.drain()
    s.set_camera(camera(), 0.0)
    (first,) = renders(s.drain())
    (sample,) = renders(answer(s, first, 0.01))
    assert s.in_flight[sample.message.frame].still, "the default session refines its still"
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.02)
    assert s.drain() == [LoadScene(1, None, "library/scan.ply")]
    assert renders(answer(s, sample, 0.03)) == [], "no sample while p's scene loads"
    assert s.next_deadline(0.04) is None
    s.set_camera(camera(1), 0.05, session_id="p")
    s.node_ready(1, 0.5, session_id="p")
    (p_first,) = renders(s.drain())
    assert s.in_flight[p_first.message.frame].session == "p"
    after = answer(s, p_first, 0.6)
    assert [a.job.session for a in after if isinstance(a, PublishFrame)] == ["p"]
    assert any(s.in_flight[a.message.frame].session == DEFAULT_SESSION and s.in_flight[a.message.frame].still
               for a in renders(after)), "the default session's still goes on"


class Host:
    """What :class:`NodeCalibration` needs: a real scheduler and one node's link."""

    def __init__(self, scheduler: JobScheduler) -> None:
        self.scheduler = scheduler
        self.nodes = {1: NodeLink(1, "n1", "llvmpipe", lambda code, reason: None, can_calibrate=True)}
        self.size = (64, 32)
        self.settings = type("Settings", (), {"scene": "builtin:spheres"})()


def test_a_node_is_not_calibrated_while_a_session_awaits_its_first_frame():
    """Calibration renders on the node's one GL thread: it waits while session p's scene loads and
    its first frame is drawn (at most QUIET_WAIT_S), and is asked for once p's frame is out."""
    s = JobScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    s.set_camera(camera(), 0.0)
    answer(s, renders(s.drain())[0], 0.01)
    s.add_session("p", CONFIG, StaticBalancer(), "library/scan.ply", 0.02)
    s.drain()
    host = Host(s)
    calibration = NodeCalibration(host)
    calibration.request([1])
    assert host.nodes[1].outbox.empty(), "p's scene loads on node 1"
    s.set_camera(camera(1), 0.05, session_id="p")
    s.node_ready(1, 0.5, session_id="p")
    answer(s, renders(s.drain())[0], 0.6)
    calibration.advance()
    assert '"calibrate"' in host.nodes[1].outbox.get_nowait()


def test_a_node_holding_the_levels_of_detail_is_calibrated_at_the_moving_frames_ceiling():
    """Issue 32: a calibration at full detail of the 24.8M-triangle model took a node 3 x 17 s away
    from the moving frames; once every node holds the levels, the region is drawn at the ceiling
    bound (``lod_max_error_px``) as a moving frame is; before, at full detail."""
    s = JobScheduler(CONFIG, StaticBalancer(), scene="builtin:spheres")
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    s.set_camera(camera(), 0.0)
    answer(s, renders(s.drain())[0], 0.01)
    host = Host(s)
    calibration = NodeCalibration(host)
    calibration.request([1])
    before = json.loads(host.nodes[1].outbox.get_nowait())
    assert before["type"] == "calibrate" and "lod_error_px" not in before
    s.levels_ready(1)
    calibration.measured(host.nodes[1], 5.0)
    after = json.loads(host.nodes[1].outbox.get_nowait())
    assert after["type"] == "calibrate" and after["lod_error_px"] == CONFIG.lod_max_error_px > CONFIG.lod_error_px


def test_no_still_sample_of_another_session_starts_between_a_simulations_steps():
    """Issue 33: the default session owes still samples on node 1 while session m shows mesh steps.
    Once step 2 is on its way (loaded ahead: ``rest``), neither step 1's frame publishing nor the
    switch to step 2 starts a sample; step 2's frame goes first, then the samples go on."""
    config = SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=0, still_delay_ms=0.0, still_samples=8)
    s = FrameScheduler(config, StaticBalancer(), scene="builtin:spheres")
    s.add_session("m", CONFIG, StaticBalancer(), "mesh:g:1", 0.0)
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    s.node_ready(1, 0.0, session_id="m")
    s.drain()
    s.set_camera(camera(1), 0.0, session_id="m")
    (shown,) = renders(s.drain())
    answer(s, shown, 0.01)   # step 1 is on screen
    s.set_camera(camera(), 0.02)
    (first,) = renders(s.drain())
    (sample,) = renders(answer(s, first, 0.03))
    assert s.in_flight[sample.message.frame].still, "the default session refines its still"
    s.set_camera(camera(2), 0.04, session_id="m")   # step 1 drawn again (its camera moved)
    step_1 = next(a for a in renders(s.drain()) + renders(answer(s, sample, 0.05))
                  if s.in_flight[a.message.frame].session == "m")
    s.rest("m")   # step 2 loads ahead on node 1 while step 1 is drawn
    assert renders(answer(s, step_1, 0.06)) == [], "no sample between the steps"
    s.replace_session("m", CONFIG, StaticBalancer(), "mesh:g:2", 0.08, held=[1], keep_partition=True)
    s.set_camera(camera(2), 0.08, session_id="m")
    assert renders(s.drain()) == [], "none while step 2's nodes are told"
    s.nodes_ready([1], 0.08, session_id="m")
    (step_2,) = renders(s.drain())
    assert s.in_flight[step_2.message.frame].session == "m" and step_2.message.scene == "mesh:g:2"
    (after,) = renders(answer(s, step_2, 0.09))
    assert s.in_flight[after.message.frame].session == DEFAULT_SESSION, "then the samples go on"


def test_a_simulations_next_step_keeps_the_partition_the_balancer_learnt():
    """Issue 33: node 2 draws its half of each frame 3x as long as node 1; after a few frames the
    adaptive balancer gives node 1 more of the frame. The next mesh step (``keep_partition``) starts
    from that partition; a switch to another scene starts from an equal split."""
    config = SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=0, still_codec=None)
    s = FrameScheduler(config, StaticBalancer(), scene="builtin:spheres")
    s.add_session("m", config, create_balancer("adaptive"), "mesh:g:1", 0.0)
    for node_id in (1, 2):
        s.add_node(node_id, 0.0)
        s.node_ready(node_id, 0.0, session_id="m")
    s.drain()

    def frame(now: float) -> dict[int, int]:
        """One frame of m at ``now``, node 2 three times as slow: each node's pixels."""
        s.set_camera(camera(int(now * 100)), now, session_id="m")
        pixels = {}
        for action in renders(s.drain()):
            job = s.in_flight[action.message.frame]
            for tile in action.message.tiles:
                ms = (3.0 if action.node_id == 2 else 1.0) * tile.rect.area / 1000
                header = TileHeader(job.frame_id, tile.tile, tile.rect, job.codec, ms, 0.0, 0.0, state_tag(None))
                s.tile_arrived(action.node_id, header, b"", now + 0.001)
                s.tile_sent(action.node_id, job.frame_id, tile.tile, 0.0)
                pixels[action.node_id] = pixels.get(action.node_id, 0) + tile.rect.area
        s.drain()
        return pixels

    first = frame(0.0)
    assert first[1] == first[2], "the first frame is an equal split"
    for step in range(1, 12):
        learnt = frame(0.2 * step)
    assert learnt[1] > 1.5 * learnt[2]
    s.replace_session("m", config, create_balancer("adaptive"), "mesh:g:2", 3.0, held=[1, 2], keep_partition=True)
    s.nodes_ready([1, 2], 3.0, session_id="m")
    kept = frame(3.1)
    assert kept[1] > 1.5 * kept[2], "the next step goes on from the learnt partition"
    s.replace_session("m", config, create_balancer("adaptive"), "library/other.ply", 4.0, held=[1, 2])
    s.nodes_ready([1, 2], 4.0, session_id="m")
    fresh = frame(4.1)
    assert fresh[1] == fresh[2], "another scene starts from an equal split"
