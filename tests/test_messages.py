"""The control message catalogue (tessera/wire/messages.py): every message round-trips through its JSON
text, bad input is refused with the field named, and decoding is bounded (size, NaN, nesting)."""

from __future__ import annotations

import json

import pytest

from tessera.geometry import Camera, Rect
from tessera.scene.state import ObjectState, SceneState, StateDelta
from tessera.wire.codec import Codec
from tessera.wire.messages import (
    FROM_NODE,
    FROM_VIEWER,
    MAX_JSON_BYTES,
    MAX_REASON,
    TO_NODE,
    Calibrate,
    Calibration,
    CameraUpdate,
    Cancel,
    Capabilities,
    DepthRequest,
    InvalidMessage,
    LatencyReport,
    LevelsReady,
    LoadScene,
    Message,
    NodeHello,
    Render,
    RenderError,
    RenderTile,
    SceneError,
    SceneGroups,
    SceneProgress,
    SceneReady,
    ShareSpec,
    TilesDropped,
    TileSent,
    ViewerError,
    ViewerHello,
    ViewerScene,
    ViewerSize,
    Welcome,
    parse,
)
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError

CAMERA = Camera(eye=(0.0, 1.0, 5.0), target=(0.0, 0.0, 0.0), fovy_deg=40.0)
BOUNDS = ((-1.0, -2.0, -3.0), (1.0, 2.0, 3.0))

EXAMPLES: list[Message] = [
    NodeHello(name="n1", token="t", renderer="llvmpipe", version=PROTOCOL_VERSION,
              capabilities=Capabilities(slowdown=2.0, calibrate=True)),
    SceneProgress(scene="builtin:cluster", fraction=0.5, message="chunking"),
    SceneReady(triangles=1200, bounds=BOUNDS,
               groups=SceneGroups(boxes=[(0.0, 0.0, 0.0, 1.0, 1.0, 1.0)], counts=[1200])),
    SceneError(scene="x.ply", message="no such file"),
    TileSent(frame=3, tile=1, send_ms=0.25, stats={"triangles": 10, "cull_ms": 0.5, "cull_path": "cpu"}),
    RenderError(frame=3, tile=1, message="out of memory"),
    TilesDropped(frame=4, tiles=(0, 2)),
    Calibration(ms=4.5),
    Welcome(node_id=7),
    LoadScene(scene="builtin:spheres", background=(0.1, 0.2, 0.3)),
    Render(frame=5, camera=CAMERA, size=(640, 480), codec=Codec.PNG, jpeg_quality=60,
           tiles=(RenderTile(tile=0, rect=Rect(0, 0, 320, 480)), RenderTile(tile=1, rect=Rect(320, 0, 320, 480)))),
    Calibrate(camera=CAMERA, size=(640, 480), rect=Rect(0, 0, 64, 64), repeats=2),
    Cancel(frames=(5, 6)),
    ViewerHello(size=(640, 480), viewer=2, camera=CAMERA, bounds=None, balancer="static",
                balancers=("static", "adaptive-predict"), frame=0),
    CameraUpdate(camera=CAMERA, seq=12),
    ViewerScene(bounds=BOUNDS, camera=CAMERA),
    ViewerError(message="bad camera"),
    LatencyReport(p50_ms=40.0, p90_ms=60.0, samples=30.0, interval_ms=33.3),
    ViewerSize(size=(1600, 900)),
    # the depth modes (issue 10)
    Render(frame=6, camera=CAMERA, size=(640, 480), codec=Codec.JPEG,
           tiles=(RenderTile(tile=1, rect=Rect(320, 0, 320, 480)),),
           depth=DepthRequest(mode="hybrid", tiles=(Rect(0, 0, 320, 480), Rect(320, 0, 320, 480)), strip=32)),
    Render(frame=7, camera=CAMERA, size=(640, 480), codec=Codec.PNG,
           tiles=(RenderTile(tile=0, rect=Rect(0, 0, 640, 480)),), depth=DepthRequest(mode="sort-last", share=3)),
    LoadScene(scene="x.ply", share=ShareSpec(version=3, index=1, weights=(1.0, 2.5))),
    SceneReady(triangles=600, bounds=BOUNDS, share=3),
    NodeHello(name="n2", version=PROTOCOL_VERSION, capabilities=Capabilities(calibrate=True, depth=True)),
]
DIGEST = "0123456789abcdef" * 4
#: Sessions (issue 19): several scenes per node, scene files fetched by digest.
SESSIONS: list[Message] = [
    LoadScene(scene="/scenes/bunny.ply", sha256=DIGEST, url="/api/scenes/bunny/file"),
    LoadScene(scene="x.ply", sha256=DIGEST, url="https://coordinator.example/api/scenes/x/file",
              share=ShareSpec(version=2, index=0, weights=(1.0,))),
    Render(frame=8, camera=CAMERA, size=(64, 64), codec=Codec.PNG, tiles=(RenderTile(tile=0, rect=Rect(0, 0, 8, 8)),),
           scene="builtin:cluster"),
    Calibrate(camera=CAMERA, size=(64, 64), rect=Rect(0, 0, 8, 8), scene="builtin:spheres"),
    SceneReady(scene="builtin:cluster", triangles=10, bounds=BOUNDS),
]


#: Big models (issues 31, 32): memory in progress, levels of detail, a frame's bound.
BIG_MODELS: list[Message] = [
    SceneProgress(scene="big.ply", fraction=0.3, message="reading big.ply", rss_mb=812.5),
    LevelsReady(scene="big.ply", nodes=40, triangles=90_000),
    LevelsReady(scene="big.ply", share=2, nodes=2, triangles=900, group_errors=[[0.0, 0.25]],
                group_triangles=[[1000.0, 250.0]], group_boxes=[[[0, 0, 0, 1, 1, 1], [0, 0, 0, 1, 1, 1.5]]]),
    Render(frame=3, camera=CAMERA, size=(64, 48), codec=Codec.JPEG,
           tiles=(RenderTile(tile=0, rect=Rect(0, 0, 64, 48)),), lod_error_px=0.5),
    Calibrate(camera=CAMERA, size=(64, 48), rect=Rect(16, 12, 32, 24), lod_error_px=1.0),
]


@pytest.mark.parametrize("message", [*EXAMPLES, *SESSIONS, *BIG_MODELS], ids=lambda m: type(m).__name__)
def test_every_message_round_trips_through_its_text(message):
    text = message.to_text()
    data = json.loads(text)
    assert data["type"] == message.kind
    assert ": " not in text and ", " not in text, "compact separators"
    assert parse(text, [type(message)]) == message
    assert parse(text.encode(), [type(message)]) == message


def test_every_kind_is_catalogued_once_per_direction():
    for direction in (FROM_NODE, TO_NODE, FROM_VIEWER):
        kinds = [cls.kind for cls in direction]
        assert len(kinds) == len(set(kinds)), kinds
    assert {type(m) for m in [*EXAMPLES, *BIG_MODELS]} >= {*FROM_NODE, *TO_NODE, *FROM_VIEWER}


def test_render_carries_the_wire_forms():
    data = EXAMPLES[10].to_json()
    assert data["codec"] == "png"
    assert data["camera"] == CAMERA.to_json()
    assert data["tiles"][1] == {"tile": 1, "rect": [320, 0, 320, 480]}
    assert data["size"] == [640, 480]


def test_depth_fields_are_left_out_where_there_are_none():
    """Sort-first messages are byte for byte what they were before the depth modes."""
    assert "depth" not in EXAMPLES[10].to_json() and "share" not in LoadScene(scene="s").to_json()
    assert "share" not in EXAMPLES[2].to_json()
    hybrid = EXAMPLES[-5].to_json()["depth"]
    assert hybrid == {"mode": "hybrid", "tiles": [[0, 0, 320, 480], [320, 0, 320, 480]], "strip": 32, "share": 0}


def test_session_fields_are_left_out_where_there_are_none():
    """Messages without a scene, digest or url are byte for byte what they were before sessions."""
    for message in EXAMPLES:
        assert not {"sha256", "url"} & set(message.to_json())
        if isinstance(message, Render | Calibrate | SceneReady):
            assert "scene" not in message.to_json()
    assert SESSIONS[0].to_json() == {"type": "load_scene", "scene": "/scenes/bunny.ply", "background": None,
                                     "sha256": DIGEST, "url": "/api/scenes/bunny/file"}
    assert SESSIONS[2].to_json()["scene"] == "builtin:cluster" and SESSIONS[3].to_json()["scene"] == "builtin:spheres"


@pytest.mark.parametrize(("fields", "fragment"), [
    ({"sha256": "0" * 63}, "load_scene.sha256"),
    ({"sha256": "A" * 64}, "load_scene.sha256"),
    ({"sha256": "0" * 65}, "load_scene.sha256"),
    ({"sha256": DIGEST, "url": "x" * 2049}, "load_scene.url"),
    ({"sha256": DIGEST, "url": ""}, "load_scene.url"),
    ({"sha256": DIGEST, "url": "ftp://host/x.ply"}, "load_scene: url must be an http(s) URL"),
    ({"url": "/api/scenes/x/file"}, "load_scene: a url needs the sha256"),
    ({"sha256": DIGEST, "url": 3}, "load_scene.url"),
])
def test_a_scene_digest_and_url_are_checked(fields, fragment):
    with pytest.raises(InvalidMessage) as caught:
        parse(json.dumps({"type": "load_scene", "scene": "x.ply", **fields}), [LoadScene])
    assert str(caught.value).startswith(fragment), str(caught.value)


def test_old_messages_name_no_scene():
    """A coordinator or node from before sessions: no scene named, none echoed."""
    render = parse(EXAMPLES[10].to_text(), [Render])
    assert render.scene is None and parse(EXAMPLES[11].to_text(), [Calibrate]).scene is None
    assert parse(EXAMPLES[2].to_text(), [SceneReady]).scene is None
    load = parse(EXAMPLES[9].to_text(), [LoadScene])
    assert (load.sha256, load.url) == (None, None)


def test_camera_update_leaves_out_a_missing_seq():
    assert "seq" not in CameraUpdate(camera=CAMERA).to_json()
    assert CameraUpdate(camera=CAMERA, seq=0).to_json()["seq"] == 0


def test_fields_a_side_does_not_know_are_ignored():
    hello = {"type": "hello", "name": "old", "version": PROTOCOL_VERSION,
             "capabilities": {"codecs": ["png", "jpeg"], "slowdown": 1.0}}
    assert parse(json.dumps(hello), [NodeHello]).capabilities == Capabilities(slowdown=1.0)
    ready = {"type": "scene_ready", "scene": "s", "meshes": 2, "chunks": 9, "load_ms": 3.0, "triangles": 5,
             "bounds": [[0, 0, 0], [1, 1, 1]]}
    assert parse(json.dumps(ready), [SceneReady]).triangles == 5


@pytest.mark.parametrize(("data", "where"), [
    ({"type": "render", "frame": 1, "camera": CAMERA.to_json(), "size": [64, 64], "codec": "png",
      "tiles": [{"tile": 0, "rect": [0, 0, 8]}]}, "render.tiles.0.rect"),
    ({"type": "render", "frame": 1, "camera": CAMERA.to_json(), "size": [64, 0], "codec": "png", "tiles": []},
     "render.size.1"),
    ({"type": "render", "frame": 1, "camera": CAMERA.to_json(), "size": [64, 64], "codec": "gif", "tiles": []},
     "render.codec"),
    ({"type": "tile_sent", "frame": 1, "tile": 0, "send_ms": -1.0}, "tile_sent.send_ms"),
    ({"type": "tile_sent", "frame": True, "tile": 0, "send_ms": 1.0}, "tile_sent.frame"),
    ({"type": "tile_sent", "frame": 1, "tile": 0, "send_ms": 1.0, "stats": {"x": "y" * 41}}, "tile_sent.stats.x"),
    ({"type": "scene_ready", "triangles": 1, "bounds": [[0, 0, 0], [1, 1, 1]],
      "groups": {"boxes": [[0, 0, 0, 1, 1, 1]], "counts": []}}, "scene_ready.groups"),
    ({"type": "calibrate", "camera": CAMERA.to_json(), "size": [64, 64], "rect": [0, 0, 8, 8], "repeats": 500},
     "calibrate.repeats"),
    ({"type": "camera", "camera": CAMERA.to_json(), "seq": 2**32}, "camera.seq"),
    ({"type": "camera", "camera": {"eye": [0, 0, 1], "target": [0, 0, 1]}}, "camera.camera"),
    ({"type": "latency", "p50_ms": 1.0, "p90_ms": 2.0, "samples": 3.0}, "latency.interval_ms"),
    ({"type": "render", "frame": 1, "camera": CAMERA.to_json(), "size": [64, 64], "codec": "png", "tiles": [],
      "depth": {"mode": "hybrid", "strip": 8}}, "render.depth"),
    ({"type": "render", "frame": 1, "camera": CAMERA.to_json(), "size": [64, 64], "codec": "png", "tiles": [],
      "depth": {"mode": "sort-first"}}, "render.depth.mode"),
    ({"type": "load_scene", "scene": "s", "share": {"version": 1, "index": 2, "weights": [1.0, 1.0]}},
     "load_scene.share"),
    ({"type": "load_scene", "scene": "s", "share": {"version": 1, "index": 0, "weights": [0.0]}},
     "load_scene.share.weights.0"),
    ({"type": "hello", "name": "n", "version": PROTOCOL_VERSION - 1}, "hello"),
])
def test_a_wrong_field_is_named_in_the_reason(data, where):
    allowed = [*FROM_NODE, *TO_NODE, *FROM_VIEWER, NodeHello]
    with pytest.raises(InvalidMessage) as caught:
        parse(json.dumps(data), [cls for cls in allowed if cls.kind == data["type"]])
    reason = str(caught.value)
    assert reason.startswith(where), reason
    assert caught.value.kind == data["type"] and caught.value.data == data


def test_an_old_protocol_version_is_refused_for_that_alone():
    with pytest.raises(InvalidMessage, match=f"protocol version 1, coordinator speaks {PROTOCOL_VERSION}"):
        parse(json.dumps({"type": "hello", "name": "n", "version": 1}), [NodeHello])


@pytest.mark.parametrize(("text", "fragment"), [
    ("{not json", "malformed JSON"),
    ("[1, 2]", "must be a JSON object"),
    ('{"type": "camera", "camera": NaN}', "NaN is not allowed"),
    ('{"type": "calibration", "ms": Infinity}', "Infinity is not allowed"),
    ('{"type": "calibration", "ms": 1e999}', "overflows to infinity"),
    ('{"type": "render"}', "unexpected message type 'render'; expected one of ['calibration', 'cancel']"),
    ('{"kind": "calibration"}', "unexpected message type None"),
    ("[" * 100_000 + "]" * 100_000, "malformed JSON"),
])
def test_undecodable_text_is_a_protocol_error(text, fragment):
    with pytest.raises(ProtocolError) as caught:
        parse(text, [Calibration, Cancel])
    assert fragment in str(caught.value)
    assert len(str(caught.value)) <= MAX_REASON


def test_size_limit_is_checked_before_decoding():
    padding = " " * (MAX_JSON_BYTES - len('{"type":"calibration","ms":1.5}'))
    assert parse('{"type":"calibration","ms":1.5}' + padding, [Calibration]).ms == 1.5
    with pytest.raises(ProtocolError, match="exceeds"):
        parse('{"type":"calibration","ms":1.5}' + padding + " ", [Calibration])


def test_reasons_are_bounded_whatever_the_peer_sends():
    huge_type = "x" * 10_000
    with pytest.raises(ProtocolError) as caught:
        parse(json.dumps({"type": huge_type}), [Calibration])
    assert len(str(caught.value)) == MAX_REASON and str(caught.value).endswith("…")
    with pytest.raises(ProtocolError) as caught:
        parse(json.dumps({"type": "calibration", "ms": "1" * 10_000}), [Calibration])
    assert len(str(caught.value)) <= MAX_REASON


def test_messages_are_frozen():
    with pytest.raises(ValueError, match="frozen"):
        EXAMPLES[8].node_id = 3  # type: ignore[misc]


def test_scene_ready_carries_objects_and_keyframes():
    ready = SceneReady(triangles=10, bounds=BOUNDS, objects=[
        {"name": "car", "translation": [1.0, 0.0, 0.0], "bounds": BOUNDS, "triangles": 10},
        {"name": "wheel", "parent": "car", "rotation": [0.0, 0.0, 0.0, 1.0], "visible": False}],
        animations=[{"name": "drive", "channels": [{"target": "car", "path": "translation", "interpolation": "STEP",
                                                    "times": [0.0, 1.0], "values": [[0, 0, 0], [1, 0, 0]]}]}])
    assert parse(ready.to_text(), [SceneReady]) == ready
    assert ready.objects is not None and ready.objects[1].parent == "car" and not ready.objects[1].visible
    with pytest.raises(InvalidMessage, match=r"scene_ready\.animations\.0\.channels\.0\.path"):
        parse(json.dumps({**ready.to_json(), "animations": [{"name": "x", "channels": [
            {"target": "car", "path": "weights", "interpolation": "STEP", "times": [], "values": []}]}]}),
            [SceneReady])


def test_render_carries_a_state_or_a_delta_and_leaves_out_none():
    state = SceneState(3, 0.5, {"car": ObjectState((1.0, 2.0, 3.0))})
    delta = StateDelta(3, 4, 0.75, {"car": ObjectState(visible=False)})
    for payload in (state, delta):
        render = Render(frame=5, camera=CAMERA, size=(64, 64), codec=Codec.PNG, tiles=(), state=payload)
        parsed = parse(render.to_text(), [Render])
        assert parsed.state is not None and parsed.state.to_json() == payload.to_json()
        assert type(parsed.state) is type(payload)
    assert "state" not in EXAMPLES[10].to_json()
    bad = {**EXAMPLES[10].to_json(), "state": {"version": 1, "time": 0.0, "objects": {"car": {"scale": [0, 1, 1]}}}}
    with pytest.raises(InvalidMessage, match=r"render\.state: car\.scale must be non-zero"):
        parse(json.dumps(bad), [Render])
