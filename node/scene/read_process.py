"""Reading a scene file into what the GL thread uploads (:func:`read_scene`), and a child process that
does it (:class:`SceneReaderProcess`), so that a node loads a new scene without stalling the tiles
it draws for other sessions.

Parsing and splitting a large scan is seconds of Python and numpy; in a thread of the node it would
hold the GIL the GL thread needs. The child process has a GIL of its own and runs at a lower CPU
priority (``nice`` +:data:`READER_NICE`), from its first instruction: a thread of that priority
starts it, so the child and every thread it starts (numpy's included) inherit it. It sends progress
and then the read scene back over a pipe. Small files and the built-in scenes are read in the loader
thread: starting the child (a new interpreter importing numpy and trimesh) costs more than they
take. Why, measured: docs/explanation/design-notes.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import os
import threading
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from node.gl.renderer import pack_geometry
from node.scene.data import SceneData
from node.scene.loading import ProgressCallback, load_scene
from node.scene.mesh import SceneError
from node.scene.shares import keep_share
from tessera.wire.messages import ShareSpec

#: Files at least this large (bytes) are read in the child process.
READ_IN_PROCESS_BYTES = 4 << 20
#: How much lower the child's CPU priority is than the node's (``nice`` increment).
READER_NICE = 10


@dataclass(frozen=True, eq=False)
class ReadScene:
    """A scene read for upload: its data and :func:`node.gl.renderer.pack_geometry` of its batches
    (interleaved vertices float32 (V, k), indices uint32 (3·T,))."""

    scene: SceneData
    packed: tuple[np.ndarray, np.ndarray]


def read_scene(source: str, spec: str, face_limit: int, share: ShareSpec | None,
               progress: ProgressCallback) -> ReadScene:
    """Parse ``source`` (a path or ``builtin:NAME``; the scene is named ``spec``), split into chunks of
    at most ``face_limit`` faces, keep ``share`` (None: the whole scene), pack. Raises SceneError."""
    scene = load_scene(source, progress, face_limit)
    if source != spec:
        scene = dataclasses.replace(scene, name=spec)
    if share is not None:
        progress(0.8, f"keeping share {share.index + 1} of {len(share.weights)}")
        scene = keep_share(scene, share.weights, share.index)
    return ReadScene(scene, pack_geometry(scene.batches))


def reads_in_process(source: str, threshold_bytes: int = READ_IN_PROCESS_BYTES) -> bool:
    """True when ``source`` is a file of at least ``threshold_bytes``."""
    with contextlib.suppress(OSError):
        return Path(source).is_file() and Path(source).stat().st_size >= threshold_bytes
    return False


class SceneReaderProcess:
    """A child process (started on first use, kept for the next) that runs :func:`read_scene`.
    :meth:`read` blocks its caller (the node's loader thread) until the scene is back; one read
    at a time. A child that dies (killed for memory, say) fails that read with SceneError and is
    started again for the next."""

    def __init__(self, nice: int = READER_NICE) -> None:
        self.nice = nice
        self._process: multiprocessing.process.BaseProcess | None = None
        self._connection: Connection | None = None

    def read(self, source: str, spec: str, face_limit: int, share: ShareSpec | None,
             progress: ProgressCallback) -> ReadScene:
        """:func:`read_scene` in the child; its progress reaches ``progress`` here. Raises its SceneError."""
        connection = self._started()
        try:
            connection.send((source, spec, face_limit, share))
            while True:
                kind, *payload = connection.recv()
                if kind == "progress":
                    progress(*payload)
                elif kind == "error":
                    raise SceneError(payload[0])
                else:
                    result: ReadScene = payload[0]
                    return result
        except (EOFError, OSError):
            code = self._stop()
            raise SceneError(f"{spec}: the scene reader process died (exit code {code}) "
                             "while reading it; out of memory?") from None

    def close(self) -> None:
        """Stop the child (a read under way is lost)."""
        self._stop()

    def _started(self) -> Connection:
        if self._connection is None or self._process is None or not self._process.is_alive():
            self._stop()
            context = multiprocessing.get_context("spawn")
            ours, theirs = context.Pipe()
            self._process = context.Process(target=_serve, args=(theirs,), name="tessera-scene-reader", daemon=True)
            _start_lowered(self._process, self.nice)
            theirs.close()
            self._connection = ours
        return self._connection

    def _stop(self) -> int | None:
        """Stop the child; its exit code (None: none was running)."""
        connection, process = self._connection, self._process
        self._connection = self._process = None
        if connection is not None:
            connection.close()
        if process is None:
            return None
        process.join(timeout=2.0)
        if process.exitcode is None:
            process.kill()
            process.join()
        return process.exitcode


def _start_lowered(process: multiprocessing.process.BaseProcess, increment: int) -> None:
    """Start ``process`` from a thread of its own whose niceness is raised by ``increment`` first
    (Linux: a thread's own), so the child is born at that priority; the caller's is left as it was
    (lowering it back would need privileges)."""
    def start() -> None:
        with contextlib.suppress(OSError):
            os.nice(increment)
        process.start()

    starter = threading.Thread(target=start, name="tessera-scene-reader-start")
    starter.start()
    starter.join()


def _serve(connection: Connection) -> None:
    """The child: read each request, answer progress messages then the scene (or an error line),
    until the node closes the pipe."""

    def report(fraction: float, message: str) -> None:
        connection.send(("progress", fraction, message))

    while True:
        try:
            source, spec, face_limit, share = connection.recv()
        except (EOFError, OSError):
            return
        answer: tuple[Any, ...]
        try:
            answer = ("scene", read_scene(source, spec, face_limit, share, report))
        except SceneError as exc:
            answer = ("error", str(exc))
        except Exception as exc:   # whatever breaks a read goes back as its reason
            answer = ("error", f"{spec}: {type(exc).__name__}: {exc}")
        connection.send(answer)
