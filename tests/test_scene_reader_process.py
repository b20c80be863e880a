"""The scene reader process (node/scene/read_process.py): a large file read in a child process is
the same scene as read in the node's own thread, with its progress relayed; with a cache folder it
answers the entry it built, which opens as the scene read here; a broken file's reason comes back; a
child killed mid-read fails that read clearly and the next read starts a new one; closing the reader
kills a child that is ingesting at once; and the GL worker sends files at or over its threshold
there (and draws them like any other)."""

from __future__ import annotations

import asyncio
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from node.gl.worker import GLWorker
from node.scene.cache_folder import CacheFolder
from node.scene.data import SceneData
from node.scene.ingest import open_cached, read_scene
from node.scene.mesh import SceneError
from node.scene.read_process import READER_NICE, SceneReaderProcess, reads_in_process, ready_entry
from tessera.geometry import Rect, default_camera
from tessera.wire.messages import LoadScene, ShareSpec
from tests.conftest import scene_path, seconds

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
    assert isinstance(there, SceneData) and isinstance(here, SceneData)
    assert there.name == here.name == "library/bunny.ply"
    assert there.triangle_count == here.triangle_count > 0
    assert np.array_equal(there.bounds, here.bounds)
    assert all(np.array_equal(a.faces, b.faces) and np.array_equal(a.positions, b.positions)
               for a, b in zip(there.batches, here.batches, strict=True))
    assert progress[0][1] == "reading bun_zipper.ply" and progress[-1][1].startswith("keeping share 2")
    again = reader.read(path, "again", 4096, None, lambda f, m: None)
    assert isinstance(again, SceneData) and again.triangle_count > 0, "the child serves again"


def test_with_a_cache_folder_the_child_answers_the_entry_it_built(reader, tmp_path: Path):
    path = str(scene_path(BUNNY))
    folder = CacheFolder(tmp_path / "cache")
    share = ShareSpec(version=1, index=0, weights=(1.0, 1.0))
    for wanted in (None, share):
        entry = reader.read(path, "library/bunny.ply", 4096, wanted, lambda f, m: None, folder)
        assert isinstance(entry, Path) and entry.parent == folder.root
        scene = open_cached(entry, "library/bunny.ply")
        here = read_scene(path, "library/bunny.ply", 4096, wanted, lambda f, m: None)
        assert isinstance(here, SceneData)
        assert scene.name == "library/bunny.ply" and scene.triangle_count == here.triangle_count
        assert np.array_equal(scene.bounds, here.bounds)


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
    assert isinstance(reader.read(str(scene_path(BUNNY)), "b", 4096, None, lambda f, m: None), SceneData)


def test_a_child_killed_mid_read_fails_the_read_and_the_next_read_starts_another(reader):
    lucy = str(scene_path(LUCY))

    def kill_on_first_progress(fraction: float, message: str) -> None:
        assert reader._process is not None
        reader._process.kill()

    with pytest.raises(SceneError, match=r"scene reader process died \(exit code -9\)"):
        reader.read(lucy, "lucy", 4096, None, kill_on_first_progress)
    read = reader.read(lucy, "lucy", 4096, None, lambda f, m: None)
    assert isinstance(read, SceneData) and read.triangle_count == 239_768


def test_closing_the_reader_kills_a_child_that_is_ingesting(reader, tmp_path: Path):
    """A load nobody needs any more stops: the node's worker closes the reader when it stops, and
    the read under way fails at once, leaving no entry."""
    lucy = str(scene_path(LUCY))
    folder = CacheFolder(tmp_path / "cache")
    failed: list[BaseException] = []

    def read() -> None:
        try:
            reader.read(lucy, "lucy", 4096, None, lambda f, m: m.startswith("read") and started.set(), folder)
        except SceneError as exc:
            failed.append(exc)

    started = threading.Event()
    thread = threading.Thread(target=read)
    thread.start()
    assert started.wait(seconds(60))
    reader.close()
    thread.join(seconds(10))
    assert not thread.is_alive() and failed and "died" in str(failed[0])
    assert not list(folder.root.glob("*/table.json")), "no entry is left by the killed builder"
    entry = reader.read(lucy, "lucy", 4096, None, lambda f, m: None, folder)
    assert isinstance(entry, Path) and open_cached(entry, "lucy").triangle_count == 239_768
    assert not list(folder.root.glob(".*.tmp")), "the next builder removes what the killed one left"


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


def test_an_entry_the_folder_holds_is_opened_without_the_reader_and_a_torn_one_is_left_to_it(reader, tmp_path: Path):
    """After a restart (the digest remembered, the entry there), the entry is checked and opened in
    the caller's thread: no reader process to start. An entry that fails its check, or a file
    whose digest is not known, is left to the reader (which rebuilds it)."""
    path = str(scene_path(BUNNY))
    folder = CacheFolder(tmp_path / "cache")
    share = ShareSpec(version=1, index=0, weights=(1.0, 1.0))
    assert ready_entry(path, 4096, None, folder) is None, "nothing built yet"
    for wanted in (None, share):
        built = reader.read(path, "library/bunny.ply", 4096, wanted, lambda f, m: None, folder)
        assert ready_entry(path, 4096, wanted, folder) == built
    assert ready_entry(path, 4096, None, None) is None and ready_entry("builtin:cluster", 4096, None, folder) is None
    whole = ready_entry(path, 4096, None, folder)
    assert whole is not None
    array = max((p for p in whole.iterdir() if p.suffix != ".json"), key=lambda p: p.stat().st_size)
    with array.open("r+b") as file:   # one flipped byte
        file.seek(array.stat().st_size // 2)
        byte = file.read(1)
        file.seek(-1, os.SEEK_CUR)
        file.write(bytes([byte[0] ^ 0xFF]))
    assert ready_entry(path, 4096, None, folder) is None
    rebuilt = reader.read(path, "library/bunny.ply", 4096, None, lambda f, m: None, folder)
    assert ready_entry(path, 4096, None, folder) == rebuilt
    copy = tmp_path / "bunny.ply"   # the same bytes under another path: its digest is not known here
    copy.write_bytes(Path(path).read_bytes())
    assert ready_entry(str(copy), 4096, None, folder) is None
