"""The scene cache folder (issue 31, ``--scene-cache-dir``): entries named by the content they were
built from, built once by whichever process needs one first, kept within a size bound.

- **By content.** An entry is named ``<sha256>-f<face limit>-v<format>`` (:mod:`node.scene.cache`), the
  SHA-256 of the scene file's bytes, as the coordinator names uploads: the same file in two
  sessions, after a restart or on a node that joins is the same entry. So that a file is not hashed
  again on every open, the digest of a path is remembered with the file's size, modification time and
  inode (``paths/``), as ``git`` remembers its index.
- **Built once.** A process that finds no entry takes the entry's lock (``<name>.lock``, ``flock``),
  looks again, and builds it only if still absent; the others wait on the lock and then open what it
  built. A lock dies with its process, so a builder killed midway leaves its temporary directory
  (removed by the next builder) and no entry.
- **Bounded.** After each build, the least recently opened entries and fetched files are deleted
  until the folder is within ``limit_bytes`` (the one just built stays). An entry being built (its
  lock held) is not deleted; a process that mapped an entry keeps its pages when it is.

To clear the cache, delete the folder (or its contents) while no node runs.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from node.scene.cache import CACHE_FORMAT, TABLE, CacheError, Progress, entry_info, read_table, remove_entry
from node.scene.digests import DigestMemo
from node.scene.mesh import SceneError

#: Seconds between two looks at a lock another process holds.
LOCK_POLL_S = 0.1
#: The folder's default bound, in MiB (``--scene-cache-mb``).
DEFAULT_CACHE_MB = 20480
#: Times an entry that fails its check is built again before the load fails.
REBUILDS = 1


def entry_name(sha256: str, face_limit: int) -> str:
    """The name of the entry of the file whose SHA-256 is ``sha256``, split with ``face_limit``."""
    return f"{sha256}-f{face_limit}-v{CACHE_FORMAT}"


def share_name(whole: str, weights: tuple[float, ...], index: int) -> str:
    """The name of share ``index`` over ``weights`` of entry ``whole``."""
    digest = hashlib.sha256(json.dumps([float(w) for w in weights]).encode()).hexdigest()[:12]
    return f"{whole}-s{index}of{len(weights)}-{digest}"


@dataclass(frozen=True, slots=True)
class CacheFolder:
    """The cache folder ``root``, kept within ``limit_bytes``."""

    root: Path
    limit_bytes: int = DEFAULT_CACHE_MB << 20

    def content_hash(self, path: Path, progress: Progress) -> str:
        """The SHA-256 of the file at ``path``: remembered while its size, modification time and inode
        stay the same (:class:`node.scene.digests.DigestMemo`), else read and hashed (progress
        reported by bytes)."""
        def report(done: int, total: int) -> None:
            progress(0.1 * done / max(total, 1), f"hashing {path.name}: {done >> 20} of {total >> 20} MB")

        return DigestMemo(self.root / "paths").digest(path, report)

    def known_hash(self, path: Path) -> str | None:
        """The SHA-256 of the file at ``path`` when remembered (:meth:`content_hash`), else None;
        never reads the file."""
        with contextlib.suppress(OSError):
            return DigestMemo(self.root / "paths").known(path)
        return None

    def entry(self, name: str) -> Path:
        return self.root / name

    def ensure(self, name: str, build: Callable[[Path], int], progress: Progress,
               format_version: int = CACHE_FORMAT) -> Path:
        """The entry ``name``: used as it is when there, else built by ``build(directory)`` (which
        writes it atomically and returns its bytes) under the entry's lock, once among the processes
        sharing the folder; then the folder is trimmed to its bound. An entry that fails to read
        (another format than ``format_version``, torn) is removed and built again."""
        directory = self.entry(name)
        if self._usable(directory, format_version):
            self._touch(directory)
            return directory
        self.root.mkdir(parents=True, exist_ok=True)
        with self._locked(name, progress):
            if self._usable(directory, format_version):
                self._touch(directory)
                return directory
            remove_entry(directory)
            for stale in self.root.glob(f".{name}.*.tmp"):
                shutil.rmtree(stale, ignore_errors=True)
            build(directory)
        self.trim(keep=name)
        return directory

    def existing(self, name: str, format_version: int = CACHE_FORMAT) -> Path | None:
        """The entry ``name`` when it is there and its table reads as ``format_version`` (marked
        used), else None; never builds. Its arrays are not checked here."""
        directory = self.entry(name)
        if not self._usable(directory, format_version):
            return None
        self._touch(directory)
        return directory

    def _usable(self, directory: Path, format_version: int = CACHE_FORMAT) -> bool:
        try:
            read_table(directory, format_version)
        except CacheError:
            return False
        return True

    def _touch(self, directory: Path) -> None:
        with contextlib.suppress(OSError):
            os.utime(directory / TABLE)

    @contextlib.contextmanager
    def reading(self, path: Path, progress: Progress) -> Iterator[None]:
        """Hold the lock of the file at ``path`` while it is hashed and read ahead (before its entry's
        name is known), waiting while another process holds it: one process reads a file at a time."""
        self.root.mkdir(parents=True, exist_ok=True)
        with self._locked(f"path-{hashlib.sha1(str(path.resolve()).encode()).hexdigest()}", progress):
            yield

    @contextlib.contextmanager
    def _locked(self, name: str, progress: Progress) -> Iterator[None]:
        """Hold the lock of entry ``name``, waiting (and saying so) while another process holds it."""
        with (self.root / f"{name}.lock").open("a") as lock:
            waited = False
            while True:
                try:
                    fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if not waited:
                        progress(0.1, "waiting for another process building the scene cache")
                        waited = True
                    time.sleep(LOCK_POLL_S)
            try:
                yield
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def held(self, name: str) -> bool:
        """Whether some process holds the lock of entry ``name`` (building or using it)."""
        path = self.root / f"{name}.lock"
        if not path.exists():
            return False
        with path.open("a") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(lock, fcntl.LOCK_UN)
            return False

    def usage(self) -> list[tuple[float, int, Path]]:
        """(last used, bytes, path) of every entry and fetched file in the folder."""
        items = []
        for path in self.root.iterdir() if self.root.is_dir() else ():
            if path.name.startswith(".") or path.name == "paths" or path.suffix == ".lock":
                continue
            with contextlib.suppress(OSError, CacheError):
                if path.is_dir():
                    items.append(((path / TABLE).stat().st_mtime, entry_info(path).bytes, path))
                else:
                    stat = path.stat()
                    items.append((max(stat.st_mtime, stat.st_atime), stat.st_size, path))
        return items

    def trim(self, keep: str | None = None) -> list[Path]:
        """Delete the least recently used entries and files until the folder is within its bound
        (never ``keep``, nor an entry whose lock is held); returns what was deleted."""
        items = sorted(self.usage())
        total = sum(size for _, size, _ in items)
        removed = []
        for _, size, path in items:
            if total <= self.limit_bytes:
                break
            if path.name == keep or self.held(path.name):
                continue
            if path.is_dir():
                remove_entry(path)
            else:
                with contextlib.suppress(OSError):
                    path.unlink()
            total -= size
            removed.append(path)
        return removed


def checked_entry(folder: CacheFolder, whole_name: str, build_whole: Callable[[Path], int],
                  share: tuple[str, Callable[[Path, Path], int]] | None, check: Callable[[Path], object],
                  source: Path, progress: Progress, format_version: int = CACHE_FORMAT) -> Path:
    """Entry ``whole_name`` of ``folder`` built by ``build_whole(directory)`` if need be, or, with
    ``share`` = (name, build(whole, directory)), that share of it; checked by ``check(entry)``
    (raising CacheError) unless this process just wrote it; entries of ``format_version``. An entry
    that fails is removed with its whole and built again, :data:`REBUILDS` times; then SceneError."""
    built: set[str] = set()

    def noted(build: Callable[[Path], int]) -> Callable[[Path], int]:
        def noting(directory: Path) -> int:
            built.add(directory.name)
            return build(directory)
        return noting

    for attempt in range(REBUILDS + 1):
        whole = folder.ensure(whole_name, noted(build_whole), progress, format_version)
        entry = whole if share is None else folder.ensure(
            share[0], noted(lambda directory, whole=whole: share[1](whole, directory)), progress, format_version)
        if entry.name in built:   # written from the arrays it checksummed just now: nothing to check
            return entry
        try:
            progress(0.9, "checking the scene cache")
            check(entry)
            return entry
        except CacheError as exc:
            remove_entry(entry)
            if entry != whole:
                remove_entry(whole)
            if attempt == REBUILDS:
                raise SceneError(f"{source}: its scene cache {entry} fails again after a rebuild ({exc})") from None
            progress(0.1, f"the scene cache failed its check ({exc}); building it again")
    raise AssertionError("unreachable")
