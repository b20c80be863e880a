"""The SHA-256 of scene files, remembered (issue 31): a file is hashed again only when its path,
size, modification time, inode or device changed, as ``git`` remembers its index. Coordinator and
nodes name scenes and scene cache entries by this digest; hashing a 471 MB PLY costs seconds, on
every session opened after a restart without this memo.

One small JSON file per path in ``folder`` (named by the SHA-1 of the resolved path), written
atomically; none (``folder`` None) keeps the memo in memory only.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path

#: Bytes hashed at a time.
HASH_BLOCK = 8 << 20


class DigestMemo:
    """Digests of files by their signature (path, size, mtime ns, inode, device), kept in ``folder``."""

    def __init__(self, folder: Path | None) -> None:
        self.folder = folder
        self._known: dict[str, tuple[list[object], str]] = {}

    @staticmethod
    def _signature(path: Path) -> tuple[str, list[object]]:
        resolved = str(path.resolve())
        stat = path.stat()
        return resolved, [resolved, stat.st_size, stat.st_mtime_ns, stat.st_ino, stat.st_dev]

    def _file(self, resolved: str) -> Path | None:
        return None if self.folder is None else self.folder / f"{hashlib.sha1(resolved.encode()).hexdigest()}.json"

    def known(self, path: Path) -> str | None:
        """The remembered digest of ``path`` while its signature holds, else None (raises OSError
        when it cannot be stat'ed)."""
        resolved, signature = self._signature(path)
        remembered = self._known.get(resolved)
        if remembered is None and (file := self._file(resolved)) is not None:
            with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
                text = json.loads(file.read_text())
                remembered = (text["signature"], str(text["sha256"]))
        if remembered is None or remembered[0] != signature:
            return None
        self._known[resolved] = remembered
        return remembered[1]

    def remember(self, path: Path, sha256: str) -> None:
        """``sha256`` is the digest of ``path`` as it is now."""
        resolved, signature = self._signature(path)
        self._known[resolved] = (signature, sha256)
        file = self._file(resolved)
        if file is None:
            return
        with contextlib.suppress(OSError):
            file.parent.mkdir(parents=True, exist_ok=True)
            partial = file.with_name(f".{file.name}.{os.getpid()}.part")
            partial.write_text(json.dumps({"signature": signature, "sha256": sha256}))
            os.replace(partial, file)

    def digest(self, path: Path, progress: Callable[[int, int], None] = lambda done, total: None) -> str:
        """The SHA-256 (hex) of the file at ``path``: remembered, else read and hashed (``progress(bytes
        done, bytes in all)`` after each block) and remembered."""
        found = self.known(path)
        if found is not None:
            return found
        hasher, done = hashlib.sha256(), 0
        # Read into one buffer, reused: no new block of memory each time, and, unlike a map of the
        # file, no SIGBUS that would kill the process if the file shrinks while it is hashed.
        block = memoryview(bytearray(HASH_BLOCK))
        with path.open("rb", buffering=0) as file:
            total = os.fstat(file.fileno()).st_size
            while read := file.readinto(block):
                hasher.update(block[:read])
                done += read
                progress(done, total)
        sha256 = hasher.hexdigest()
        self.remember(path, sha256)
        return sha256
