"""Meshes sent as arrays (issue 33: ``Session.update_mesh``, ``PUT /api/sessions/{id}/mesh``): the wire
layout and its checks, the node's store, and against a real coordinator with two local nodes: each
update shows (its still equals ``--render-once`` of the same mesh as a PLY file), a burst of updates
never shows a torn frame, bad input is refused with its reason and the session keeps its frames, a
watch key changes nothing."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from types import SimpleNamespace

import httpx
import numpy as np
import pytest
import trimesh

from bench.mesh_steps import height_field, wave
from node.scene.mesh import SceneError
from node.scene.mesh_store import MeshStore
from node.scene.normals import smooth_vertex_normals
from node.scene.octree import chunk_boxes
from server.mesh_updates import MeshUpdates
from tessera.client import Tessera, TesseraError
from tessera.scheduling.refinement import DEFAULT_STILL_SAMPLES
from tessera.wire.mesh_update import MeshArrays, MeshError, checked_mesh, pack_mesh, unpack_mesh, with_header
from tests.conftest import Coordinator, seconds, start_coordinator
from tests.integration_support import assert_matches_reference, render_once, wait_until

SIZE = (160, 120)
CAMERA = {"eye": [2.0, 1.5, 2.0], "target": [0, 0, 0], "up": [0, 1, 0], "fovy_deg": 45}
#: Straight down on a plane that fills the view at every height of :func:`plane`.
TOP_CAMERA = {"eye": [0.0, 3.0, 0.0], "target": [0, 0, 0], "up": [0, 0, -1], "fovy_deg": 40}
#: The burst's colours, one a step (distinct hues, told apart after lighting and JPEG).
HUES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, 0, 1], [0, 1, 1]], dtype=np.float64)


def plane(height: float, color: np.ndarray, cells: int = 8) -> dict[str, np.ndarray]:
    """A horizontal square ±4 at ``height`` of 2 × ``cells``² triangles, every vertex ``color``:
    ``update_mesh``'s arguments."""
    grid, faces = height_field(2 * cells * cells)
    vertices = grid * 4.0
    vertices[:, 1] = height
    return {"vertices": vertices, "faces": faces, "colors": np.tile(color, (len(vertices), 1))}


# ----------------------------------------------------------------- the layout, no GL


def test_a_mesh_packs_and_unpacks_with_every_array():
    vertices, faces, colors = plane(0.5, HUES[2], cells=3).values()
    normals = np.tile([0.0, 1.0, 0.0], (len(vertices), 1))
    header, mesh = unpack_mesh(pack_mesh(checked_mesh(vertices, faces, normals, colors), scene="mesh:a:b"))
    assert header["scene"] == "mesh:a:b" and header["vertices"] == len(vertices)
    assert np.array_equal(mesh.positions, vertices.astype(np.float32)) and np.array_equal(mesh.faces, faces)
    assert mesh.normals is not None and np.array_equal(mesh.normals, normals)
    assert mesh.colors is not None and mesh.colors.dtype == np.uint8 and (mesh.colors[0] == [0, 0, 255, 255]).all()


@pytest.mark.parametrize(("arrays", "reason"), [
    (([[0, 0, 0], [1, 0, 0], [0, float("nan"), 1]], [[0, 1, 2]]), "finite"),
    (([[0, 0], [1, 0], [0, 1]], [[0, 1, 2]]), "N×3"),
    (([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 3]]), "0…2"),
    (([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0.0, 1.0, 2.0]]), "integer"),
])
def test_bad_arrays_are_refused_with_the_reason(arrays, reason):
    with pytest.raises(MeshError, match=reason):
        checked_mesh(*arrays)


def test_a_message_of_the_wrong_size_or_values_is_refused():
    good = pack_mesh(checked_mesh(**plane(0.0, HUES[0], cells=2)))
    with pytest.raises(MeshError, match="need"):
        unpack_mesh(good[:-4])
    with pytest.raises(MeshError, match="TMSH"):
        unpack_mesh(b"XXXX" + good[4:])
    vertices = np.zeros((3, 3), np.float32)
    vertices[1, 2] = np.inf
    with pytest.raises(MeshError, match="finite"):
        unpack_mesh(pack_mesh(MeshArrays(vertices, np.array([[0, 1, 2]], np.uint32))))
    with pytest.raises(MeshError, match="0…2"):
        unpack_mesh(pack_mesh(MeshArrays(np.zeros((3, 3), np.float32), np.array([[0, 1, 7]], np.uint32))))


def test_the_node_keeps_the_newest_mesh_of_a_group_and_builds_its_scene():
    store = MeshStore()
    first, second = (pack_mesh(checked_mesh(**plane(h, HUES[0], cells=4)), scene=f"mesh:g:{h}") for h in (1, 2))
    store.receive(first)
    store.receive(second)
    with pytest.raises(SceneError, match="superseded"):
        store.scene("mesh:g:1", 1000)
    scene = store.scene("mesh:g:2", 10)
    assert scene.triangle_count == 32 and scene.chunks.chunk_count > 1 and scene.bounds[0][1] == 2.0
    assert [o.name for o in scene.objects.objects] == ["mesh"]
    with pytest.raises(SceneError, match="no such mesh"):
        store.scene("mesh:other:1", 1000)


def test_the_node_keeps_the_step_shown_while_the_next_loads():
    store = MeshStore()
    mesh = checked_mesh(**plane(1.0, HUES[0], cells=2))
    store.receive(pack_mesh(mesh, scene="mesh:g:1"))
    store.receive(pack_mesh(mesh, scene="mesh:g:2", keep="mesh:g:1"))   # step 2 loads while step 1 is shown
    assert store.live("mesh:g:1") and store.live("mesh:g:2")
    store.receive(pack_mesh(mesh, scene="mesh:g:3", keep="mesh:g:1"))   # step 3 takes step 2's place
    assert store.live("mesh:g:1") and not store.live("mesh:g:2") and store.live("mesh:g:3")
    with pytest.raises(SceneError, match="superseded"):
        store.scene("mesh:g:2", 1000)
    assert store.scene("mesh:g:1", 1000).triangle_count == store.scene("mesh:g:3", 1000).triangle_count == 8
    store.receive(pack_mesh(mesh, scene="mesh:g:4", keep="mesh:g:3"))
    assert not store.live("mesh:g:1") and store.live("mesh:g:3") and store.live("mesh:g:4")


def test_a_step_of_the_same_faces_keeps_the_chunks_of_the_step_before():
    """A simulation's next step (the same faces, the vertices moved) keeps the step before's chunks
    and orders, with the boxes and smooth normals of its own positions; a step whose vertices moved
    far (every chunk would span the mesh), or with other faces, is split afresh."""
    store = MeshStore()
    grid, faces = height_field(20_000)

    def step(name: str, vertices: np.ndarray, faces: np.ndarray = faces):
        store.receive(pack_mesh(checked_mesh(vertices, faces), scene=f"mesh:g:{name}"))
        scene = store.scene(f"mesh:g:{name}", 192)
        return scene, scene.batches[0]

    first, first_batch = step("1", wave(grid, 0.0))
    second, batch = step("2", wave(grid, 0.5))
    assert np.array_equal(batch.faces, first_batch.faces), "the chunks and orders of the step before"
    assert np.array_equal(second.chunks.index_bounds, first.chunks.index_bounds)
    assert not np.array_equal(batch.positions, first_batch.positions)
    starts = second.chunks.index_bounds[:-1] // 3
    assert np.array_equal(second.chunks.boxes, chunk_boxes(batch.positions, batch.faces, starts))
    assert np.array_equal(batch.normals, smooth_vertex_normals(batch.positions, batch.faces))
    _, scrambled = step("3", np.random.default_rng(1).permutation(wave(grid, 1.0)))
    assert not np.array_equal(scrambled.faces, first_batch.faces), "split afresh: far from the old chunks"
    _, other = step("4", wave(grid, 1.5), faces[::-1].copy())
    assert not np.array_equal(other.faces, scrambled.faces), "other faces: split afresh"


def test_a_message_with_a_new_header_keeps_its_arrays():
    mesh = checked_mesh(**plane(0.5, HUES[1], cells=3))
    body = pack_mesh(mesh)
    header, again = unpack_mesh(with_header(body, scene="mesh:a:b", keep=None))
    assert header["scene"] == "mesh:a:b" and header["keep"] is None
    assert np.array_equal(again.positions, mesh.positions) and np.array_equal(again.faces, mesh.faces)
    assert again.colors is not None and mesh.colors is not None and np.array_equal(again.colors, mesh.colors)


class FakeService:
    """What :class:`MeshUpdates` asks of the service: switching counts frame ids up; each node's
    messages are kept in order."""

    def __init__(self) -> None:
        self.sessions = {"s": SimpleNamespace(id="s", scene="builtin:cluster", state="ready")}
        self.sent: dict[int, list] = {1: [], 2: []}
        self.nodes = {i: SimpleNamespace(send_bytes=sent.append, send=sent.append) for i, sent in self.sent.items()}
        self.rested: list[str] = []
        self.scheduler = SimpleNamespace(load_now=lambda session_id: None, rest=self.rested.append)
        self.settings = SimpleNamespace(mode="sort-first")
        self.switched: list[tuple[str, dict]] = []

    def switch_scene(self, session, name, spec, fetch, camera=None, held=None, keep_partition=False) -> int:
        assert keep_partition, "a mesh step keeps the partition of the step before"
        session.scene = spec
        self.switched.append((spec, dict(held or {})))
        return 10 * len(self.switched)

    def load_message(self, scene):
        return ("load", scene)

    def apply(self) -> None:
        pass


def test_a_step_waits_until_the_one_before_is_shown_and_the_latest_waiting_wins():
    async def run() -> None:
        service = FakeService()
        meshes, session = MeshUpdates(service), service.sessions["s"]
        body = pack_mesh(checked_mesh(**plane(0.0, HUES[0], cells=2)))
        assert await meshes.update(session, body) == 10
        first = service.switched[0][0]
        meshes.before_load(1, first)
        meshes.before_load(1, first)   # a node has the bytes once
        assert [unpack_mesh(m)[0]["scene"] for m in service.sent[1]] == [first]
        second, third = (asyncio.ensure_future(meshes.update(session, body)) for _ in range(2))
        await asyncio.sleep(0.01)
        assert not second.done() and not third.done() and len(service.switched) == 1
        meshes.published("s", 9)    # a frame of the step before the mesh: the mesh is not shown yet
        await asyncio.sleep(0.01)
        assert not second.done()
        meshes.published("s", 10)
        assert await second == await third == 20 and len(service.switched) == 2   # the second's step skipped
        fourth = asyncio.ensure_future(meshes.update(session, body))
        await asyncio.sleep(0.01)
        assert not fourth.done()
        meshes.published("s", 21)
        assert await fourth == 30

    asyncio.run(asyncio.wait_for(run(), 5.0))


def test_a_step_waiting_is_loaded_ahead_and_switched_in_where_it_is_held():
    async def run() -> None:
        service = FakeService()
        meshes, session = MeshUpdates(service), service.sessions["s"]
        body = pack_mesh(checked_mesh(**plane(0.0, HUES[0], cells=2)))
        await meshes.update(session, body)
        shown = service.switched[0][0]
        waiting = asyncio.ensure_future(meshes.update(session, body))
        await asyncio.sleep(0.01)
        assert service.rested == ["s"]    # the step shown is drawn once, no settle frames or still
        for node_id, sent in service.sent.items():   # every node: the bytes, then the load of them
            header = unpack_mesh(sent[0])[0]
            assert header["keep"] == shown and sent[1] == ("load", header["scene"])
            if node_id == 1:
                assert meshes.loaded_ahead(1, SimpleNamespace(scene=header["scene"]))
        assert not meshes.loaded_ahead(2, SimpleNamespace(scene=shown))
        meshes.published("s", 10)
        await asyncio.sleep(0.05)
        assert not waiting.done()   # node 2 has not answered yet: its first frame would be node 1's alone
        assert not meshes.failed_ahead(2, shown) and meshes.failed_ahead(2, header["scene"])
        assert await waiting == 20
        spec, held = service.switched[1]
        assert spec == header["scene"] and list(held) == [1]
        meshes.before_load(2, spec)   # sent already with the load ahead
        assert len(service.sent[2]) == 2

    asyncio.run(asyncio.wait_for(run(), 5.0))


# ----------------------------------------------------------------- against a real coordinator


@pytest.fixture(scope="module")
def coordinator(tmp_path_factory) -> Iterator[Coordinator]:
    started = start_coordinator("--local-nodes", "2", "--size", f"{SIZE[0]}x{SIZE[1]}", "--max-upload-mb", "1",
                                "--data-dir", str(tmp_path_factory.mktemp("data")))
    yield started
    started.proc.stop()


@pytest.fixture
def tessera(coordinator) -> Iterator[Tessera]:
    with Tessera(coordinator.url, timeout=seconds(120)) as client:
        yield client


def reference(vertices: np.ndarray, faces: np.ndarray, camera: dict, workdir) -> np.ndarray:
    """``--render-once`` of the still of the mesh written as a PLY file."""
    path = workdir / f"mesh-{len(list(workdir.glob('mesh-*.ply')))}.ply"
    trimesh.Trimesh(vertices=vertices.astype(np.float32), faces=faces, process=False).export(path)
    return render_once(str(path), camera, SIZE, workdir, still_samples=DEFAULT_STILL_SAMPLES)


@pytest.mark.integration
@pytest.mark.gl
def test_each_update_shows_equal_to_render_once_of_the_same_mesh(tessera, tmp_path):
    grid, faces = height_field(2000)
    with tessera.open_session("builtin:cluster", size=SIZE, camera=CAMERA) as session:
        for step in (1, 2):
            vertices = wave(grid, 0.7 * step)
            first = session.update_mesh(vertices, faces)
            frame_id, still = session.snapshot_frame(still=True)
            assert frame_id >= first and session.info().scene == "mesh"
            assert_matches_reference(still, reference(vertices, faces, CAMERA, tmp_path), f"step {step}")


def steps_shown(image: np.ndarray) -> set[int]:
    """The burst's steps whose hue the image's pixels have (each pixel: the nearest hue)."""
    pixels = image.reshape(-1, 3).astype(np.float64) + 1.0
    pixels /= np.linalg.norm(pixels, axis=1, keepdims=True)
    hues = HUES / np.linalg.norm(HUES, axis=1, keepdims=True)
    return set(np.unique(np.argmax(pixels @ hues.T, axis=1)).tolist())


@pytest.mark.integration
@pytest.mark.gl
def test_a_burst_of_updates_never_shows_a_torn_frame(coordinator, tessera):
    with tessera.open_session("builtin:cluster", size=SIZE, camera=TOP_CAMERA) as session, \
            Tessera(coordinator.url, timeout=seconds(120)) as reader:
        session.update_mesh(**plane(0.0, HUES[0]))
        session.snapshot(still=False)
        frames: list[tuple[int, np.ndarray]] = []
        done = threading.Event()

        def read() -> None:
            for frame in reader.session(session.id).frames(timeout=seconds(60)):
                frames.append(frame)
                if done.is_set():
                    return

        thread = threading.Thread(target=read, daemon=True)
        thread.start()
        firsts = []
        for step in range(1, len(HUES)):   # every other step waits to be shown; the others are superseded
            firsts.append(session.update_mesh(**plane(0.2 * step, HUES[step])))
            session.orbit(0.5)   # a frame in flight when the next step comes
            if step % 2:
                wait_until(lambda: any(frame_id >= firsts[-1] for frame_id, _ in frames), seconds(30),
                           f"a frame of step {step}")
        last_id, last = session.snapshot_frame(still=False, after=firsts[-1])
        assert steps_shown(last) == {len(HUES) - 1}
        done.set()
        session.orbit(1.0)   # one more frame, so that the reader returns
        thread.join(seconds(30))
    assert frames and max(frame_id for frame_id, _ in frames) >= last_id
    for frame_id, image in frames:
        shown = steps_shown(image)
        assert len(shown) == 1, f"frame {frame_id} mixes steps {sorted(shown)}"
        step = shown.pop()
        assert step == 0 or frame_id >= firsts[step - 1], f"frame {frame_id} shows step {step} too early"
        later = [s for s, first in enumerate(firsts, start=1) if frame_id >= first]
        assert not later or step >= later[-1], f"frame {frame_id} shows step {step}, after step {later[-1]}'s first"


@pytest.mark.integration
@pytest.mark.gl
def test_bad_meshes_are_refused_with_reasons_and_the_session_keeps_its_frames(coordinator, tessera):
    with tessera.open_session("builtin:cluster", size=SIZE, camera=CAMERA) as session:
        vertices, faces = height_field(200)
        session.update_mesh(vertices, faces)
        before_id, before = session.snapshot_frame(still=False)
        with pytest.raises(TesseraError, match="finite"):
            session.update_mesh(np.full((3, 3), np.nan), [[0, 1, 2]])
        url = f"{coordinator.url.rstrip('/')}/api/sessions/{session.id}/mesh"
        nan = np.zeros((3, 3), np.float32)
        nan[0, 0] = np.nan
        bodies = {
            "finite": pack_mesh(MeshArrays(nan, np.array([[0, 1, 2]], np.uint32))),
            "0…2": pack_mesh(MeshArrays(np.zeros((3, 3), np.float32), np.array([[0, 1, 3]], np.uint32))),
            "need": pack_mesh(checked_mesh(vertices, faces))[:-8],
            "TMSH": b"not a mesh",
        }
        for reason, body in bodies.items():
            answer = httpx.put(url, content=body, headers={"content-type": "application/octet-stream"})
            assert answer.status_code == 422 and reason in answer.json()["detail"], answer.text
        big = np.zeros((100_000, 3), np.float32)
        with pytest.raises(TesseraError, match="--max-upload-mb") as refused:
            session.update_mesh(big, np.zeros((1, 3), np.int64))
        assert refused.value.status == 413
        with pytest.raises(TesseraError) as default:
            tessera.session("default").update_mesh(vertices, faces)
        assert default.value.status == 409
        assert session.info().state == "ready" and session.info().scene == "mesh"
        session.orbit(0.0)
        after_id, after = session.snapshot_frame(still=False)
        assert after_id > before_id and np.abs(after.astype(int) - before.astype(int)).mean() < 2.0


@pytest.mark.integration
@pytest.mark.gl
def test_a_watch_key_cannot_send_a_mesh(coordinator):
    base = coordinator.url.rstrip("/")
    opened = httpx.post(f"{base}/api/sessions", json={"scene": "builtin:cluster", "size": list(SIZE)}).json()
    key = opened["watch_url"].split("session=")[1].split("&")[0]
    body = pack_mesh(checked_mesh(*height_field(50)))
    try:
        answer = httpx.put(f"{base}/api/sessions/{key}/mesh", content=body)
        assert answer.status_code == 403 and "watch" in answer.json()["detail"]
        assert httpx.get(f"{base}/api/sessions/{opened['id']}").json()["scene"] == "builtin:cluster"
    finally:
        httpx.delete(f"{base}/api/sessions/{opened['id']}")


@pytest.mark.integration
@pytest.mark.gl
def test_a_sessions_last_mesh_step_comes_back_after_a_coordinator_restart(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    grid, faces = height_field(2000)
    args = ("--local-nodes", "2", "--size", f"{SIZE[0]}x{SIZE[1]}", "--data-dir", str(data))
    first = start_coordinator(*args)
    try:
        with Tessera(first.url, timeout=seconds(120)) as client:
            session = client.open_session("builtin:cluster", size=SIZE, camera=CAMERA)
            session.update_mesh(wave(grid, 0.3), faces)
            before = session.update_mesh(wave(grid, 1.1), faces)   # the last step is the one kept
            frame_id, shown = session.snapshot_frame(still=True)
            assert frame_id >= before
            assert first.proc.stop() == 0   # with the session open
    finally:
        first.proc.stop()
    assert [p.name for p in (data / "meshes").iterdir()] == [f"{session.id}.tmsh"]
    second = start_coordinator(*args)
    try:
        with Tessera(second.url, timeout=seconds(120)) as client:
            again = client.session(session.id)
            assert again.info().scene == "mesh"
            _, restored = again.snapshot_frame(still=True)
            assert_matches_reference(restored, shown, "the mesh step after the restart")
            assert_matches_reference(restored, reference(wave(grid, 1.1), faces, CAMERA, tmp_path), "its render-once")
            again.close()
    finally:
        second.proc.stop()
    assert not list((data / "meshes").iterdir()), "a closed session's mesh is removed"
