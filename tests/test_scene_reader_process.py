"""The scene reader process (node/scene/read_process.py): a large file read in a child process is
the same scene as read in the node's own thread, with its progress relayed; a broken file's reason
comes back; a child killed mid-read fails that read clearly and the next read starts a new one;
and the GL worker sends files at or over its threshold there (and draws them like any other)."""

from __future__ import annotations

import asyncio
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from node.gl.worker import GLWorker
from node.scene.mesh import SceneError
from node.scene.read_process import READER_NICE, SceneReaderProcess, read_scene, reads_in_process
from tessera.geometry import Rect, default_camera
from tessera.wire.messages import LoadScene, ShareSpec
from tests.conftest import scene_path

BUNNY = "bunny/bun_zipper.ply"
LUCY = "large_scan/stanford_lucy_240k.ply"


@pytest.fixture
def reader():
    process = SceneReaderProcess()
    yield process
    process.close()


def test_a_file_read_in_the_child_is_the_scene_read_here(reader):
    path = str(scene_path(BUNNY))
    share = ShareSpec(version=1, index=1, weights=(1.0, 2.0))
    progress: list[tuple[float, str]] = []
    there = reader.read(path, "library/bunny.ply", 4096, share, lambda f, m: progress.append((f, m)))
    here = read_scene(path, "library/bunny.ply", 4096, share, lambda f, m: None)
    assert there.scene.name == here.scene.name == "library/bunny.ply"
    assert there.scene.triangle_count == here.scene.triangle_count > 0
    assert np.array_equal(there.scene.bounds, here.scene.bounds)
    assert all(np.array_equal(a, b) for a, b in zip(there.packed, here.packed, strict=True))
    assert progress[0][1] == "reading bun_zipper.ply" and progress[-1][1].startswith("keeping share 2")
    assert reader.read(path, "again", 4096, None, lambda f, m: None).scene.triangle_count > 0, "the child serves again"


def test_every_thread_of_the_child_runs_at_the_lower_priority_and_the_callers_keeps_its_own(reader):
    """Born lowered: its start-up and the threads numpy starts at import are lowered too."""
    before = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    reader.read(str(scene_path(BUNNY)), "library/bunny.ply", 4096, None, lambda f, m: None)
    assert reader._process is not None
    tasks = list(Path(f"/proc/{reader._process.pid}/task").iterdir())
    niceness = {int(task.joinpath("stat").read_text().rsplit(")", 1)[1].split()[16]) for task in tasks}
    assert niceness == {min(before + READER_NICE, 19)}, f"{len(tasks)} threads at {niceness}"
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == before


def test_a_broken_file_comes_back_with_its_reason(reader, tmp_path: Path):
    broken = tmp_path / "broken.ply"
    broken.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\nend_header\n\x00\x01")
    with pytest.raises(SceneError, match=r"broken\.ply: corrupt or unreadable PLY"):
        reader.read(str(broken), "broken.ply", 4096, None, lambda f, m: None)
    assert reader.read(str(scene_path(BUNNY)), "b", 4096, None, lambda f, m: None).scene.triangle_count > 0


def test_a_child_killed_mid_read_fails_the_read_and_the_next_read_starts_another(reader):
    lucy = str(scene_path(LUCY))

    def kill_on_first_progress(fraction: float, message: str) -> None:
        assert reader._process is not None
        reader._process.kill()

    with pytest.raises(SceneError, match=r"scene reader process died \(exit code -9\)"):
        reader.read(lucy, "lucy", 4096, None, kill_on_first_progress)
    assert reader.read(lucy, "lucy", 4096, None, lambda f, m: None).scene.triangle_count == 239_768


def test_files_over_the_threshold_are_read_in_the_child(tmp_path: Path):
    bunny = scene_path(BUNNY)
    size = bunny.stat().st_size
    assert reads_in_process(str(bunny), size) and not reads_in_process(str(bunny), size + 1)
    assert not reads_in_process("builtin:cluster", 0) and not reads_in_process(str(tmp_path / "missing.ply"), 0)


@pytest.mark.gl
def test_the_worker_draws_a_scene_read_in_the_child_like_one_read_in_its_thread():
    path = str(scene_path(BUNNY))

    async def drawn(threshold: int) -> tuple[np.ndarray, bool]:
        worker = GLWorker(read_in_process_bytes=threshold)
        await worker.start()
        try:
            loaded = await worker.load(LoadScene(scene=path), lambda f, m: None)
            camera = default_camera(loaded.scene.bounds, aspect=96 / 64)
            tile = await worker.render(camera, (96, 64), Rect(0, 0, 96, 64), 0, scene=path)
            return tile.pixels, worker._reader._process is not None
        finally:
            await asyncio.to_thread(worker.close)

    in_child, child_used = asyncio.run(drawn(0))
    in_thread, child_started = asyncio.run(drawn(1 << 40))
    assert child_used and not child_started
    assert np.array_equal(in_child, in_thread) and (in_child != in_child[0, 0]).any()
