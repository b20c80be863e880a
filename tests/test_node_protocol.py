"""The node's protocol core (node/protocol.py) without sockets or GL: coordinator text in, actions
out — the welcome and cancels at once, jobs in order, superseded scene loads skipped, scene states
applied in message order, malformed messages refused with their reason; loads in the background,
a load holding back only the jobs of its own scene received after it (issue 19)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from node.protocol import CANCELLED_MEMORY, Draw, Load, Measure, NodeAction, NodeProtocol, Send
from node.scene.loading import load_scene
from node.scene.mesh import SceneError as SceneLoadError
from node.settings import parse_settings
from tessera.scene.state import ObjectState, SceneState
from tessera.wire.messages import LoadScene, NodeHello, RenderError, SceneError, SceneReady, TilesDropped
from tessera.wire.protocol import PROTOCOL_VERSION

CAMERA = {"eye": [0.0, 1.0, 4.0], "target": [0.0, 0.0, 0.0]}
FULL = SceneState(3, 0.5, {"car": ObjectState((1.0, 2.0, 3.0))})
#: What every load in these tests is taken to have loaded (no GL: the scene's data only).
SPHERES = load_scene("builtin:spheres")


def render(frame: int, tiles: int = 2, state: dict | None = None, scene: str | None = None) -> str:
    message = {"type": "render", "frame": frame, "camera": CAMERA, "size": [64, 32], "codec": "png",
               "tiles": [{"tile": i, "rect": [i * 32, 0, 32, 32]} for i in range(tiles)]}
    if state is not None:
        message["state"] = state
    if scene is not None:
        message["scene"] = scene
    return json.dumps(message)


def calibrate(scene: str | None = None) -> str:
    message = {"type": "calibrate", "camera": CAMERA, "size": [64, 32], "rect": [16, 8, 32, 16]}
    return json.dumps(message if scene is None else {**message, "scene": scene})


def load(scene: str, background: float | None = None, share: int | None = None) -> str:
    message: dict = {"type": "load_scene", "scene": scene}
    if background is not None:
        message["background"] = [background] * 3
    if share is not None:
        message["share"] = {"version": 1, "index": share, "weights": [1.0, 1.0]}
    return json.dumps(message)


def connected(*texts: str) -> NodeProtocol:
    protocol = NodeProtocol("n1", "t0k", slowdown=2.0)
    protocol.connect("llvmpipe")
    for text in texts:
        protocol.receive_text(text)
    return protocol


def drain(protocol: NodeProtocol) -> list[NodeAction]:
    """Every action the protocol hands out now, each taken as done at once (a load as loaded)."""
    actions = []
    while (action := protocol.next_action()) is not None:
        actions.append(action)
        if isinstance(action, Load):
            protocol.scene_loaded(action.request, SPHERES, None)
    return actions


def until_idle(protocol: NodeProtocol) -> list[NodeAction]:
    """Every action the protocol hands out now, each taken as done at once but loads, which go on."""
    actions = []
    while (action := protocol.next_action()) is not None:
        actions.append(action)
    return actions


def drawn(actions: list[NodeAction]) -> list[tuple[int, int]]:
    return [(a.render.frame, a.tile.tile) for a in actions if isinstance(a, Draw)]


def loads(actions: list[NodeAction]) -> list[LoadScene]:
    return [a.request for a in actions if isinstance(a, Load)]


def sent(actions: list[NodeAction]) -> list:
    return [a.message for a in actions if isinstance(a, Send)]


def test_the_hello_names_the_machine_every_node_on_it_names_alike():
    """The host id is the kernel's boot id (one per machine, the same in a container on it), so
    another process here says the same; ``--host-id`` names another machine; a bad one is refused."""
    here = parse_settings([], {}).host
    other = subprocess.run([sys.executable, "-c", "from node.settings import default_host; print(default_host())"],
                           capture_output=True, text=True, check=True).stdout.strip()
    assert here and here == other
    assert NodeProtocol("n1", host=here).connect("llvmpipe").host == here
    assert parse_settings(["--host-id", "rack-2"], {}).host == "rack-2"
    assert parse_settings([], {"TESSERA_HOST_ID": "rack-3"}).host == "rack-3"
    with pytest.raises(SystemExit):
        parse_settings(["--host-id", "x" * 65], {})


def test_connect_says_hello_and_the_welcome_takes_effect_at_once():
    protocol = NodeProtocol("n1", "t0k", slowdown=2.0)
    hello = protocol.connect("llvmpipe")
    assert isinstance(hello, NodeHello) and (hello.name, hello.token, hello.renderer) == ("n1", "t0k", "llvmpipe")
    assert hello.version == PROTOCOL_VERSION
    assert (hello.capabilities.slowdown, hello.capabilities.calibrate, hello.capabilities.depth) == (2.0, True, True)
    assert not protocol.welcomed and protocol.node_id is None
    protocol.receive_text(json.dumps({"type": "welcome", "node_id": 7}))
    assert protocol.welcomed and protocol.node_id == 7
    assert protocol.next_action() is None, "the welcome is no job"
    protocol.connect("llvmpipe")
    assert not protocol.welcomed, "each connection waits for its own welcome"


def test_jobs_come_in_message_order_one_tile_at_a_time_once_their_scene_is_loaded():
    protocol = connected(load("builtin:spheres"), render(1), calibrate())
    first = protocol.next_action()
    assert isinstance(first, Load) and first.request.scene == "builtin:spheres"
    assert protocol.next_action() is None, "the render and the calibration wait for the scene"
    ready = protocol.scene_loaded(first.request, SPHERES, None)
    assert isinstance(ready, SceneReady) and ready.scene == "builtin:spheres" and ready.share is None
    assert ready.triangles == SPHERES.triangle_count
    draws = [protocol.next_action(), protocol.next_action()]
    assert drawn(draws) == [(1, 0), (1, 1)]
    assert {a.scene for a in draws if isinstance(a, Draw)} == {"builtin:spheres"}, "the scene loaded last"
    measure = protocol.next_action()
    assert isinstance(measure, Measure) and measure.request.repeats == 3 and measure.scene == "builtin:spheres"
    assert protocol.next_action() is None


def test_of_several_loads_waiting_for_one_key_only_the_newest_is_loaded():
    protocol = connected(load("a.ply", 0.1), render(1, tiles=1), load("a.ply", 0.2), load("b.ply"),
                         load("a.ply", share=1))
    started = until_idle(protocol)
    assert [(r.scene, r.background, r.share and r.share.index) for r in loads(started)] == [
        ("a.ply", (0.2, 0.2, 0.2), None), ("b.ply", None, None), ("a.ply", None, 1)], \
        "each key once, the newest of its loads; another share is another key"
    assert drawn(started) == [], "the render waits for a.ply, whose load was received before it"
    protocol.receive_text(load("a.ply", 0.3))
    protocol.receive_text(load("a.ply", 0.4))
    assert protocol.next_action() is None, "a key's next load waits for the one under way"
    protocol.scene_loaded(started[0].request, SPHERES, None)
    actions = until_idle(protocol)
    assert [r.background for r in loads(actions)] == [(0.4, 0.4, 0.4)]
    assert drawn(actions) == [(1, 0)], "its load is done: the one that superseded the load received before it"


def test_a_load_received_while_a_tile_is_drawn_is_handed_out_at_once_and_the_next_tile_waits_its_turn():
    protocol = connected(load("a.ply"))
    drain(protocol)
    protocol.receive_text(render(1, tiles=2, scene="a.ply"))
    (first,) = drawn([protocol.next_action()])
    assert first == (1, 0)
    protocol.receive_text(load("b.ply"))   # a mesh step loaded ahead, while tile (1, 0) is drawn
    ahead = protocol.next_load()
    assert isinstance(ahead, Load) and ahead.request.scene == "b.ply", "not held until the tile is done"
    assert protocol.next_load() is None, "handed out once"
    protocol.receive_text(render(2, tiles=1, scene="b.ply"))
    assert drawn(until_idle(protocol)) == [(1, 1)], "frame 1's tiles go on; frame 2 waits for b.ply"
    protocol.scene_loaded(ahead.request, SPHERES, None)
    assert drawn(until_idle(protocol)) == [(2, 0)]


def test_a_load_holds_back_only_the_jobs_of_its_scene_received_after_it():
    protocol = connected(load("a.ply"))
    drain(protocol)
    protocol.receive_text(render(1, tiles=1, scene="b.ply"))
    protocol.receive_text(load("b.ply"))
    for text in (render(2, tiles=1, scene="a.ply"), render(3, scene="b.ply"), calibrate("b.ply"),
                 render(4, tiles=1, scene="a.ply"), render(5, tiles=1), calibrate("a.ply")):
        protocol.receive_text(text)
    actions = until_idle(protocol)
    (load_b,) = loads(actions)
    assert drawn(actions) == [(1, 0), (2, 0), (4, 0)], "a render of b before its load, and a's, go on"
    assert [a.scene for a in actions if isinstance(a, Draw)] == ["b.ply", "a.ply", "a.ply"]
    assert [a.scene for a in actions if isinstance(a, Measure)] == ["a.ply"]
    assert protocol.next_action() is None, "b's jobs wait, in order, and frame 5 (no scene: the newest, b) too"
    protocol.scene_loaded(load_b, SPHERES, None)
    actions = until_idle(protocol)
    assert drawn(actions) == [(3, 0), (3, 1), (5, 0)]
    assert [type(a) for a in actions] == [Draw, Draw, Measure, Draw], "in message order"
    assert {a.scene for a in actions if isinstance(a, Draw | Measure)} == {"b.ply"}


def test_an_old_coordinators_renders_are_of_the_scene_loaded_before_them():
    """No ``scene`` in its renders: each is of the newest load_scene before it, loads go on in parallel."""
    protocol = connected(load("a.ply"), render(1, tiles=1), load("b.ply"), render(2, tiles=1))
    load_a, load_b = loads(until_idle(protocol))
    protocol.scene_loaded(load_b, SPHERES, None)
    (draw,) = until_idle(protocol)
    assert isinstance(draw, Draw) and (draw.render.frame, draw.scene) == (2, "b.ply"), "frame 2 passes frame 1 by"
    protocol.scene_loaded(load_a, SPHERES, None)
    (draw,) = until_idle(protocol)
    assert isinstance(draw, Draw) and (draw.render.frame, draw.scene) == (1, "a.ply")
    protocol.connect("llvmpipe")
    protocol.receive_text(render(3, tiles=1))
    (draw,) = until_idle(protocol)
    assert draw.scene is None, "on a new connection before any load: whatever the node loaded last"


def test_a_failed_load_fails_the_jobs_waiting_for_it_with_the_reason():
    protocol = connected(load("a.ply"))
    drain(protocol)
    for text in (load("b.ply"), render(5, scene="b.ply"), calibrate("b.ply"), render(6, tiles=1, scene="a.ply")):
        protocol.receive_text(text)
    actions = until_idle(protocol)
    assert drawn(actions) == [(6, 0)]
    failed = protocol.scene_failed(loads(actions)[0], SceneLoadError("b.ply: no such\n file"))
    assert failed == SceneError(scene="b.ply", message="b.ply: no such file")
    errors = sent(until_idle(protocol))
    assert [(e.frame, e.tile) for e in errors] == [(5, 0), (5, 1), (0, 0)]
    assert errors[0].message == "scene b.ply failed to load: b.ply: no such file"
    assert errors[2].message == "calibration failed: scene b.ply failed to load: b.ply: no such file"
    protocol.receive_text(render(7, tiles=1, scene="b.ply"))
    assert drawn(until_idle(protocol)) == [(7, 0)], "a later render is tried (the worker says it is not loaded)"


def test_a_cancelled_frame_waits_for_no_load_and_a_load_of_an_old_connection_is_ignored():
    protocol = connected(load("b.ply"), render(8, scene="b.ply"), render(9, tiles=1, scene="b.ply"))
    (load_b,) = loads(until_idle(protocol))
    protocol.receive_text(json.dumps({"type": "cancel", "frames": [8]}))
    assert sent(until_idle(protocol)) == [TilesDropped(frame=8, tiles=(0, 1))], "dropped without waiting"
    protocol.connect("llvmpipe")
    protocol.receive_text(render(10, tiles=1, scene="b.ply"))
    assert protocol.scene_loaded(load_b, SPHERES, None).scene == "b.ply"
    assert protocol.scene_failed(load_b, RuntimeError("late")).scene == "b.ply"
    assert drawn(until_idle(protocol)) == [(10, 0)], "nothing of the old connection waits"


def test_tiles_of_a_cancelled_frame_are_dropped_and_reported_once_the_frame_is_through():
    protocol = connected(render(4, tiles=5), json.dumps({"type": "cancel", "frames": [9]}))
    assert drawn([protocol.next_action()]) == [(4, 0)]
    protocol.receive_text(json.dumps({"type": "cancel", "frames": [4]}))
    assert sent(drain(protocol)) == [TilesDropped(frame=4, tiles=(1, 2, 3, 4))], "the tiles not begun, in order"
    assert protocol.tiles_dropped == 4
    protocol.receive_text(render(4, tiles=2))
    assert sent(drain(protocol)) == [TilesDropped(frame=4, tiles=(0, 1))], "a cancel is remembered"
    assert protocol.tiles_dropped == 6


def test_the_cancel_memory_keeps_the_newest_frames():
    protocol = connected(json.dumps({"type": "cancel", "frames": list(range(CANCELLED_MEMORY + 1))}))
    protocol.receive_text(render(0, tiles=1))
    protocol.receive_text(render(CANCELLED_MEMORY, tiles=1))
    actions = drain(protocol)
    assert drawn(actions) == [(0, 0)], "the oldest cancel was forgotten"
    assert sent(actions) == [TilesDropped(frame=CANCELLED_MEMORY, tiles=(0,))]


def test_a_new_connection_forgets_the_cancelled_frames():
    """A coordinator restarted on the same address numbers its frames from the start again: a frame
    the old one cancelled is a new frame of the new one, drawn (reporting it dropped would be a
    protocol error the coordinator closes the node for)."""
    protocol = connected(json.dumps({"type": "cancel", "frames": [3]}))
    protocol.connect("llvmpipe")
    protocol.receive_text(render(3, tiles=2))
    actions = drain(protocol)
    assert drawn(actions) == [(3, 0), (3, 1)] and sent(actions) == []


def test_a_cancelled_frames_state_is_still_applied_in_message_order():
    later = SceneState(4, 0.75, {"car": ObjectState(visible=False)})
    protocol = connected(json.dumps({"type": "cancel", "frames": [5]}), render(5, tiles=1, state=FULL.to_json()),
                         render(6, tiles=1, state=later.delta_from(FULL).to_json()))
    actions = drain(protocol)
    assert sent(actions) == [TilesDropped(frame=5, tiles=(0,))]
    (draw,) = [a for a in actions if isinstance(a, Draw)]
    assert draw.render.frame == 6 and draw.state is not None
    assert draw.state.version == 4 and draw.state.same_as(later)


def test_a_state_that_does_not_apply_fails_every_tile_of_its_frame():
    delta = {"base": 9, "version": 10, "time": 0.0, "objects": {}}
    protocol = connected(render(7, tiles=2, state=delta))
    errors = sent(drain(protocol))
    assert [(e.frame, e.tile) for e in errors] == [(7, 0), (7, 1)]
    assert all(isinstance(e, RenderError) and e.message.startswith("scene state: ") for e in errors)
    assert "before any full state" in errors[0].message
    protocol = connected(render(1, tiles=1, state=FULL.to_json()))
    protocol.connect("llvmpipe")
    protocol.receive_text(render(2, tiles=1, state=FULL.patched({}).delta_from(FULL).to_json()))
    assert "before any full state" in sent(drain(protocol))[0].message, "a new connection starts without a state"


def test_malformed_messages_are_refused_in_their_turn_with_the_reason():
    bad_render = json.dumps({"type": "render", "frame": 3, "camera": CAMERA, "size": [64, 32], "codec": "webp",
                             "tiles": [{"tile": 0, "rect": [0, 0, 32, 32]}, {"tile": 1}, "x", {"tile": True}]})
    bad_calibrate = json.dumps({"type": "calibrate", "camera": CAMERA, "size": [64, 32], "rect": [0, 0, 8, 8],
                                "repeats": 0})
    bad_load = json.dumps({"type": "load_scene", "scene": "x.ply", "background": [2, 0, 0]})
    protocol = connected(render(1, tiles=1), bad_render, bad_calibrate, bad_load)
    assert drawn([protocol.next_action()]) == [(1, 0)], "the malformed ones wait their turn"
    refusals = sent(drain(protocol))
    assert [(type(r), getattr(r, "frame", None), getattr(r, "tile", None)) for r in refusals] == [
        (RenderError, 3, 0), (RenderError, 3, 1), (RenderError, 0, 0), (SceneError, None, None)]
    assert "codec" in refusals[0].message and refusals[0].message == refusals[1].message
    assert refusals[2].message.startswith("calibration failed: ") and "repeats" in refusals[2].message
    assert refusals[3].scene == "x.ply" and "background" in refusals[3].message


def test_a_refusal_answers_only_what_can_be_read_and_other_input_is_ignored():
    unreadable = json.dumps({"type": "render", "frame": "three", "tiles": [{"tile": 0}]})
    protocol = connected(unreadable, "not json", json.dumps({"type": "viewer_hello"}), json.dumps([1, 2]),
                         json.dumps({"type": "load_scene"}))
    (refusal,) = sent(drain(protocol))
    assert isinstance(refusal, SceneError) and refusal.scene == "None" and "scene" in refusal.message


def test_work_results_become_the_messages_to_send():
    protocol = connected()
    failed = protocol.scene_failed(LoadScene(scene="x.ply"), SceneLoadError("no such\n  file"))
    assert failed == SceneError(scene="x.ply", message="no such file")
    assert protocol.scene_failed(LoadScene(scene="y.ply"), RuntimeError()).message == "RuntimeError"
    assert protocol.tile_failed(3, 1, ValueError("tile [0, 0, 9, 9]\noutside")) == RenderError(
        frame=3, tile=1, message="tile [0, 0, 9, 9] outside")
    assert protocol.encoding_failed(3, 1, OSError("disk")).message == "encoding failed: disk"
    assert protocol.calibration_failed(RuntimeError("no scene\nloaded")) == RenderError(
        frame=0, tile=0, message="calibration failed: no scene loaded")
