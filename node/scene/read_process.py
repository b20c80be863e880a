"""A child process that makes scene files ready to draw (:class:`SceneReaderProcess`, running
:func:`node.scene.ingest.read_scene`), so that a node loads a new scene without stalling the tiles
it draws for other sessions.

Ingesting a large scan is seconds of Python and numpy; in a thread of the node it would hold the
GIL the GL thread needs. The child process has a GIL of its own and runs at a lower CPU priority
(``nice`` +:data:`READER_NICE`), from its first instruction: a thread of that priority starts it,
so the child and every thread it starts (numpy's included) inherit it. It sends progress and then
what it made back over a pipe: the scene cache entry's path (the node maps the entry; the geometry
never crosses the pipe), or, without a cache folder, the scene itself pickled. Small files and the
built-in scenes are read in the loader thread: starting the child (a new interpreter importing
numpy and trimesh) costs more than they take. Why, measured: docs/explanation/design-notes.md.

A node that stops kills the child at once: a load nobody needs any more does not go on for the
seconds a big file takes (an entry half built is never seen: :mod:`node.scene.cache`).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from node.scene.cache import CACHE_FORMAT, CacheError, open_entry
from node.scene.cache_folder import CacheFolder, entry_name, share_name
from node.scene.data import SceneData
from node.scene.ingest import cached_levels, read_scene
from node.scene.loading import BUILTIN_PREFIX, ProgressCallback
from node.scene.mesh import SceneError
from node.scene.point_cache import POINTS_ENTRY_FORMAT, open_points_entry, points_entry_name
from node.scene.point_files import is_point_file
from tessera.wire.messages import ShareSpec

#: Files at least this large (bytes) are read in the child process.
READ_IN_PROCESS_BYTES = 4 << 20
#: How much lower the child's CPU priority is than the node's (``nice`` increment).
READER_NICE = 10


def ready_entry(source: str, face_limit: int, share: ShareSpec | None, folder: CacheFolder | None,
                sha256: str | None = None, verify: bool = True) -> Path | None:
    """The scene cache entry of the file ``source`` (a mesh's, or a point cloud's: issue 36; its
    ``share`` only, when given), checked, when
    ``folder`` holds it already and the file's digest is known without reading the file (``sha256``,
    or remembered); None otherwise: then :func:`node.scene.ingest.read_scene` builds it (or removes
    and rebuilds one that fails the check) in the reader process. After a restart this opens a
    scene without starting the reader (a new interpreter: a second or more on a loaded machine).
    ``verify`` False: only its table and its files' shapes are checked, not their CRCs (the caller
    checks them before it draws the scene: :meth:`node.gl.worker.GLWorker.load`)."""
    if folder is None or source.startswith(BUILTIN_PREFIX):
        return None
    digest = sha256 or folder.known_hash(Path(source))
    if digest is None:
        return None
    points = is_point_file(Path(source))
    whole = points_entry_name(digest) if points else entry_name(digest, face_limit)
    entry = folder.existing(whole if share is None else share_name(whole, share.weights, share.index),
                            POINTS_ENTRY_FORMAT if points else CACHE_FORMAT)
    if entry is None:
        return None
    try:
        (open_points_entry if points else open_entry)(entry, Path(source).name, verify=verify)
    except CacheError:
        return None
    return entry


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

    def read(self, source: str, spec: str, face_limit: int, share: ShareSpec | None, progress: ProgressCallback,
             folder: CacheFolder | None = None, sha256: str | None = None) -> SceneData | Path:
        """:func:`node.scene.ingest.read_scene` in the child; its progress reaches ``progress`` here.
        Raises its SceneError."""
        result: SceneData | Path = self._ask(("scene", source, spec, face_limit, share, folder, sha256), spec, progress)
        return result

    def levels(self, entry: Path, folder: CacheFolder, progress: ProgressCallback) -> Path | None:
        """:func:`node.scene.ingest.cached_levels` in the child. Raises its SceneError."""
        result: Path | None = self._ask(("levels", entry, folder), entry.name, progress)
        return result

    def _ask(self, request: tuple[Any, ...], name: str, progress: ProgressCallback) -> Any:
        connection = self._started()
        try:
            connection.send(request)
            while True:
                kind, *payload = connection.recv()
                if kind == "progress":
                    progress(*payload)
                elif kind == "error":
                    raise SceneError(payload[0])
                else:
                    return payload[0]
        except (EOFError, OSError, TypeError):   # TypeError: close() took the handle from under recv()
            code = self._stop()
            raise SceneError(f"{name}: the scene reader process died (exit code {code}) "
                             "while reading it; out of memory?") from None

    def close(self) -> None:
        """Kill the child at once (a read under way fails with SceneError in its caller's thread)."""
        process = self._process
        if process is not None and process.is_alive():
            process.kill()
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
            kind, *arguments = connection.recv()
        except (EOFError, OSError):
            return
        answer: tuple[Any, ...]
        try:
            if kind == "levels":
                answer = ("levels", cached_levels(*arguments, report))
            else:
                source, spec, face_limit, share, folder, sha256 = arguments
                answer = ("scene", read_scene(source, spec, face_limit, share, report, folder, sha256))
        except SceneError as exc:
            answer = ("error", str(exc))
        except Exception as exc:   # whatever breaks a read goes back as its reason
            answer = ("error", f"{arguments[0]}: {type(exc).__name__}: {exc}")
        connection.send(answer)
