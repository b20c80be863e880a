"""The Python client (issue 33) against a real coordinator and real render nodes: every method of
``Tessera`` and ``Session``, every error path as one ``TesseraError`` with the coordinator's reason,
arrays uploaded equal to the same mesh uploaded as a file, and the five lines of Python whose still
equals ``--render-once``."""

from __future__ import annotations

import asyncio
import subprocess
import textwrap
import threading
from collections.abc import Iterator

import numpy as np
import pytest
import trimesh
from PIL import Image

from bench.images import psnr
from tessera.client import Camera, Tessera, TesseraError
from tessera.client.session import fitted, orbited
from tessera.scheduling.refinement import DEFAULT_STILL_SAMPLES
from tests.conftest import PYTHON, REPO, SCENES, Coordinator, scene_path, seconds, start_coordinator
from tests.integration_support import SCENE_FILES, assert_matches_reference, render_once

pytestmark = [pytest.mark.integration, pytest.mark.gl]

SIZE = (256, 192)
TOKEN = "client-secret"
BUNNY = f"library/{SCENE_FILES['bunny']}"
TRUCK = "library/gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"
CAMERA = {"eye": [0.1, 0.25, 0.3], "target": [-0.02, 0.1, 0.0], "up": [0, 1, 0], "fovy_deg": 40}


@pytest.fixture(scope="module")
def coordinator(tmp_path_factory) -> Iterator[Coordinator]:
    data = tmp_path_factory.mktemp("data")
    started = start_coordinator("--local-nodes", "2", "--size", f"{SIZE[0]}x{SIZE[1]}", "--token", TOKEN,
                                "--scenes-dir", str(SCENES), "--data-dir", str(data))
    yield started
    started.proc.stop()


@pytest.fixture
def tessera(coordinator) -> Iterator[Tessera]:
    with Tessera(coordinator.url, token=TOKEN, timeout=seconds(120)) as client:
        yield client


def still_reference(scene: str, camera: dict, size: tuple[int, int], workdir) -> np.ndarray:
    """``--render-once`` of the still the live service converges to."""
    return render_once(scene, camera, size, workdir, still_samples=DEFAULT_STILL_SAMPLES)


def test_five_lines_of_python_save_a_still_equal_to_render_once(coordinator, tmp_path):
    shot = tmp_path / "shot.png"
    five_lines = textwrap.dedent(f"""\
        from tessera.client import Tessera
        tessera = Tessera({coordinator.url!r}, token={TOKEN!r})
        session = tessera.open_session({BUNNY!r}, size=(256, 192), camera={CAMERA!r})
        session.save({str(shot)!r})
        session.close()
        """)
    assert len(five_lines.splitlines()) == 5
    result = subprocess.run([PYTHON, "-c", five_lines], cwd=tmp_path, capture_output=True, text=True,
                            timeout=seconds(180))
    assert result.returncode == 0, result.stderr
    saved = np.asarray(Image.open(shot).convert("RGB"))
    assert_matches_reference(saved, still_reference(str(scene_path(SCENE_FILES["bunny"])), CAMERA, SIZE, tmp_path),
                             "the saved still")
    assert REPO.joinpath("tessera", "client").is_dir()


def test_every_method_of_the_client(tessera, tmp_path):
    names = [scene.name for scene in tessera.scenes()]
    assert BUNNY in names and TRUCK in names and "builtin:cluster" in names
    stats = tessera.stats()
    assert stats["size"] == list(SIZE) and len(stats["nodes"]) == 2

    with tessera.open_session(TRUCK, size=(160, 120)) as session:
        assert session.id in [info.id for info in tessera.sessions()]
        assert tessera.session(session.id).size == (160, 120)
        first = session.camera
        assert isinstance(first, Camera)
        session.orbit(40)
        assert np.allclose(session.camera.eye, orbited(first, 40).eye)
        assert np.linalg.norm(np.subtract(session.camera.eye, first.target)) == pytest.approx(
            np.linalg.norm(np.subtract(first.eye, first.target)))
        session.look_at([0.5, 1.0, 0.0], eye=[4.0, 3.0, 5.0])
        assert session.camera.target == (0.5, 1.0, 0.0) and session.camera.eye == (4.0, 3.0, 5.0)
        session.fit()
        assert session.camera == fitted(Camera((4.0, 3.0, 5.0), (0.5, 1.0, 0.0)), session.bounds, (160, 120))
        session.size = (200, 100)
        assert session.size == (200, 100) and session.snapshot(still=False).shape == (100, 200, 3)

        moving = session.snapshot(still=False)
        objects = dict(session.objects)
        assert objects and all(obj.name == name for name, obj in objects.items())
        wheels = session.animation.state()["animations"][0]["targets"]
        hidden = session.objects[wheels[0]]
        hidden.visible = False
        assert hidden.visible is False
        assert np.abs(session.snapshot(still=False).astype(int) - moving).sum() > 0   # a wheel gone
        hidden.visible = True
        hidden.translation = [0.0, 0.5, 0.0]
        assert hidden.translation == [0.0, 0.5, 0.0]
        hidden.scale, hidden.rotation = [1.0, 2.0, 1.0], [0.0, 0.0, 0.0, 1.0]
        assert hidden.scale == [1.0, 2.0, 1.0]
        with pytest.raises(KeyError):
            session.objects["no such object"]

        session.animation.time = 0.5
        assert session.animation.time == pytest.approx(0.5)
        session.animation.play(speed=2.0)
        assert session.animation.playing and session.animation.speed == 2.0
        session.animation.pause()
        assert not session.animation.playing

        saved = session.save(tmp_path / "truck.png")
        still = session.snapshot()
        assert np.array_equal(np.asarray(Image.open(saved).convert("RGB")), still)
        frame_id, image = session.snapshot_frame()
        assert frame_id >= session.changed_at and np.array_equal(image, still)

        seen = []
        for frame_id, image in session.frames(timeout=seconds(60)):
            seen.append(frame_id)
            assert image.shape == (100, 200, 3)
            if len(seen) == 1:
                session.orbit(5)
            if len(seen) == 3:
                break
        assert seen == sorted(seen) and len(set(seen)) == 3

        duck = tessera.upload(scene_path("gltf_small/Duck.glb"), name="duck-for-client.glb")
        assert duck == "upload/duck-for-client.glb" and duck in [scene.name for scene in tessera.scenes()]
        camera = {"eye": [150.0, 120.0, 250.0], "target": [0.0, 80.0, 0.0], "up": [0, 1, 0], "fovy_deg": 45}
        switched = session.set_scene(duck, camera=camera)
        assert session.scene == duck
        frame_id, image = session.snapshot_frame(still=True)
        assert frame_id >= switched
        assert_matches_reference(image, still_reference(str(scene_path("gltf_small/Duck.glb")), camera, (200, 100),
                                                        tmp_path), "the session after set_scene")
    assert session.id not in [info.id for info in tessera.sessions()]


def test_the_async_twin_gives_the_same_pictures(tessera):
    with tessera.open_session(BUNNY, size=(96, 72), camera=CAMERA) as session:
        still = session.snapshot()

        async def read() -> tuple[np.ndarray, list[int]]:
            picture = await session.snapshot_async()
            seen = []
            async for frame_id, image in session.frames_async(timeout=seconds(60)):
                assert image.shape == (72, 96, 3)
                seen.append(frame_id)
                if len(seen) == 1:
                    await asyncio.to_thread(session.orbit, 10)
                if len(seen) == 2:
                    break
            return picture, seen

        picture, seen = asyncio.run(read())
        assert np.array_equal(picture, still) and seen[1] > seen[0]
    with pytest.raises(TesseraError, match="no such session"):
        asyncio.run(session.snapshot_async())


def test_arrays_upload_equals_the_same_mesh_uploaded_as_a_file(tessera, tmp_path):
    mesh = trimesh.load(scene_path(SCENE_FILES["bunny"]), process=False)
    from_arrays = tessera.upload((mesh.vertices, mesh.faces))
    assert tessera.upload((mesh.vertices, mesh.faces)) == from_arrays   # named by content: one scene
    with tessera.open_session(BUNNY, size=SIZE, camera=CAMERA) as file_session, \
            tessera.open_session(from_arrays, size=SIZE, camera=CAMERA) as array_session:
        from_file, from_mesh = file_session.snapshot(), array_session.snapshot()
    assert psnr(from_mesh, from_file) >= 50.0, f"PSNR {psnr(from_mesh, from_file):.1f} dB"
    coloured = tessera.upload((mesh.vertices, mesh.faces, None, np.tile([0.9, 0.2, 0.1], (len(mesh.vertices), 1))))
    with tessera.open_session(coloured, size=SIZE, camera=CAMERA) as session:
        red = session.snapshot()
    drawn = np.abs(red.astype(int) - red[0, 0]).sum(axis=2) > 30   # the bunny, not the background
    assert drawn.mean() > 0.05 and (red[drawn, 0].astype(int) > 2 * red[drawn, 2].astype(int)).mean() > 0.9
    with pytest.raises(ValueError, match="faces index vertices"):
        tessera.upload((mesh.vertices, mesh.faces + len(mesh.vertices)))


def no_httpx_trace(error: TesseraError) -> None:
    """Nothing of httpx's or websockets' exceptions is chained to it (no traceback of their internals)."""
    assert error.__cause__ is None and (error.__context__ is None or error.__suppress_context__)


def test_each_error_is_one_exception_with_the_coordinators_reason(coordinator, tessera):
    with pytest.raises(TesseraError, match="missing or wrong token") as wrong, \
            Tessera(coordinator.url, token="wrong") as stranger:
        stranger.sessions()
    assert wrong.value.status == 401
    no_httpx_trace(wrong.value)
    with pytest.raises(TesseraError, match="no scene named") as unknown:
        tessera.open_session("library/no/such/scene.glb")
    assert unknown.value.status == 422
    with pytest.raises(TesseraError, match="camera"):
        tessera.open_session(BUNNY, camera={"eye": [0, 0, 0], "target": [0, 0, 0]})
    with pytest.raises(TesseraError, match="no such session"):
        tessera.session("not-a-session")

    session = tessera.open_session(BUNNY, size=(64, 48))
    frames = session.frames()
    assert next(frames)[1].shape == (48, 64, 3)
    closer = threading.Timer(0.2, session.close)
    closer.start()
    with pytest.raises(TesseraError, match="session closed") as closed_socket:
        for _ in frames:
            pass
    closer.join()
    assert closed_socket.value.close_code == 4404
    for call in (session.snapshot, lambda: session.orbit(10), lambda: session.set_scene(TRUCK)):
        with pytest.raises(TesseraError, match="no such session") as closed:
            call()
        assert closed.value.status == 404
        no_httpx_trace(closed.value)
    with pytest.raises(TesseraError, match="no such session"):
        next(session.frames())


def test_a_coordinator_gone_mid_call_is_one_clear_error(tmp_path):
    lonely = start_coordinator("--size", "64x48")   # no nodes: a frame is waited for, never drawn
    try:
        with Tessera(lonely.url, timeout=seconds(60)) as tessera:
            session = tessera.open_session("builtin:spheres")
            waiting = threading.Timer(1.0, lonely.proc.stop)
            waiting.start()
            with pytest.raises(TesseraError, match=r"went away|cannot reach") as gone:
                session.snapshot()
            waiting.join()
            no_httpx_trace(gone.value)
            assert gone.value.status is None
            with pytest.raises(TesseraError, match="cannot reach"):
                tessera.scenes()
    finally:
        lonely.proc.stop()


def test_a_scene_that_fails_to_load_is_an_error_with_the_nodes_reason(coordinator_factory, tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    (scenes / "broken.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\nnot numbers\n")
    coordinator = coordinator_factory("--local-nodes", "1", "--size", "64x48", "--scenes-dir", str(scenes))
    with Tessera(coordinator.url, timeout=seconds(120)) as tessera, \
            tessera.open_session("library/broken.ply") as session:
        with pytest.raises(TesseraError, match="did not load") as failed:
            session.snapshot()
        assert "broken.ply" in failed.value.reason and failed.value.reason.split("did not load: ", 1)[1]


def test_record_writes_a_film_of_every_frame_and_poster_equals_render_once(tessera, tmp_path):
    """Session.record (issue 35): the MP4 of a camera path plays back one frame per camera at the
    size asked (PyAV); an orbit too; Session.poster equals render-once; failures carry the reason."""
    import av

    with tessera.open_session(BUNNY, size=(320, 240), camera=CAMERA) as session:
        session.wait_ready()
        cameras = [orbited(Camera.from_json(CAMERA), 10.0 * k) for k in range(5)]
        seen: list[tuple[int, int]] = []
        film = session.record(cameras, tmp_path / "path.mp4", fps=10, size=(160, 120),
                              progress=lambda done, total: seen.append((done, total)))
        with av.open(str(film)) as container:
            frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
        assert len(frames) == 5 and frames[0].shape == (120, 160, 3) and seen[-1] == (5, 5)
        orbit = session.record(orbit=(0.5, 1.0), out=tmp_path / "orbit.mp4", fps=8, size=(96, 64))
        with av.open(str(orbit)) as container:
            assert sum(1 for _ in container.decode(video=0)) == 8
        poster = session.poster((300, 200), tmp_path / "poster.png", samples=2)
        reference = render_once(str(scene_path(SCENE_FILES["bunny"])), CAMERA, (300, 200), tmp_path, still_samples=2)
        assert np.array_equal(np.asarray(Image.open(poster).convert("RGB")), reference)
        with pytest.raises(TesseraError, match=r"16x16 to \d+x\d+ px \(--max-poster-size\)") as refused:
            session.poster((8, 8), tmp_path / "tiny.png")
        assert refused.value.status == 422
        with pytest.raises(TesseraError, match="one of path and orbit"):
            session.record(out=tmp_path / "none.mp4")
