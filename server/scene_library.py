"""The scenes a session may show (issue 19): the built-in ones, the files of ``--scenes-dir`` (read
only) and the uploads kept in ``--data-dir``/scenes, each under one name.

Names: ``builtin:NAME``; ``library/PATH`` for a file of ``--scenes-dir`` (``PATH`` relative to it,
``/``-separated, sub-folders included); ``upload/FILE`` for an upload. Hidden files and folders
(a leading ``.``) are never listed or served, nor is a symlink whose target lies outside its folder;
symlinked folders are not entered. Uploads are written to a hidden temporary file beside their
final place, flushed to disk, then linked under their name, which fails if the name was taken: a
crash leaves at most a hidden temporary file (removed at the next start), never a half-written
scene under its name.

File system access is here; HTTP is in :mod:`server.routes.scenes`.
"""

from __future__ import annotations

import hashlib
import logging
import os
import secrets
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from node.scene.builtin import BUILTIN_SCENES
from node.scene.digests import DigestMemo
from node.scene.loading import BUILTIN_PREFIX, SUPPORTED_SUFFIXES, load_scene
from node.scene.mesh import SceneError
from node.scene.objects import GLTF_SUFFIXES
from node.scene.point_files import is_point_file, read_points
from tessera.scene.gltf import GltfError, read_document
from tessera.scene.gltf_pack import self_contained_gltf

log = logging.getLogger("tessera.server")

LIBRARY_PREFIX = "library/"
UPLOAD_PREFIX = "upload/"
#: Uploads live in this folder of ``--data-dir``.
UPLOADS_FOLDER = "scenes"
#: Where the digests of library files and uploads are remembered, in the data folder.
DIGESTS_FOLDER = "digests"
#: How an upload's temporary file starts: hidden, so never listed, and removed at start-up.
TEMPORARY_PREFIX = ".upload-"
#: Longest file name most file systems take, in UTF-8 bytes, less room for the temporary prefix.
MAX_NAME_BYTES = 255 - len(TEMPORARY_PREFIX) - 17


#: Why an upload is refused when uploads are off.
UPLOADS_OFF = "uploads are off: start the coordinator with --data-dir DIR to turn them on"


class SceneRefused(ValueError):
    """A scene name or upload the library turns down; the message says why."""


class UnknownScene(SceneRefused):
    """No scene has this name."""


class BadSceneName(SceneRefused):
    """An upload's file name the library does not take."""


class UnsupportedFormat(SceneRefused):
    """A file whose suffix is none of :data:`SUPPORTED_SUFFIXES`."""


class SceneExists(SceneRefused):
    """An upload under a name already taken."""


class UploadTooLarge(SceneRefused):
    """An upload over ``--max-upload-mb``."""


class NotAScene(SceneRefused):
    """An uploaded file that does not load as a scene."""


class TooLargeToLoad(SceneRefused):
    """An uploaded file whose check needs more memory than ``--upload-check-memory-mb``."""


class UploadsUnavailable(SceneRefused):
    """Uploads are off (no ``--data-dir``) or their folder cannot be written."""


@dataclass(frozen=True)
class SceneEntry:
    """One scene: its ``name``, ``format`` (``builtin`` or the file suffix), size in ``bytes`` (0 for
    a built-in scene) and ``path`` (None for a built-in scene)."""

    name: str
    format: str
    bytes: int
    path: Path | None = None

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "format": self.format, "bytes": self.bytes}

    @property
    def spec(self) -> str:
        """What a node's ``load_scene`` takes: ``builtin:NAME`` or the file's path."""
        return self.name if self.path is None else str(self.path)


def scene_format(path: Path) -> str:
    return path.suffix.lower().lstrip(".")


def _part_refusal(part: str) -> str | None:
    """Why ``part`` may not be one component of a scene name (a file or folder name), or None."""
    if not part:
        return "an empty name"
    if "/" in part or "\\" in part:
        return "a name with '/' or '\\'"
    if ".." in part:
        return "a name with '..'"
    if part.startswith("."):
        return "a hidden name (starting with '.')"
    if any(unicodedata.category(ch).startswith("C") for ch in part):
        return "a name with control or unassigned characters"
    if len(part.encode("utf-8", errors="replace")) > MAX_NAME_BYTES:
        return f"a name over {MAX_NAME_BYTES} bytes"
    return None


def _inside(path: Path, root: Path) -> bool:
    """Whether ``path``, symlinks resolved, lies in ``root`` (resolved)."""
    return path.resolve().is_relative_to(root)


def _scene_file(root: Path, parts: list[str]) -> Path | None:
    """The regular file ``root/parts…`` when it may be listed and served: every part a plain name,
    a supported suffix, no symlinked folder on the way, and the file itself (symlinks resolved)
    in ``root``."""
    if not parts or any(_part_refusal(part) for part in parts):
        return None
    if not parts[-1].lower().endswith(SUPPORTED_SUFFIXES):
        return None
    path = root.joinpath(*parts)
    folder = root
    for part in parts[:-1]:
        folder = folder / part
        if folder.is_symlink():
            return None
    return path if path.is_file() and _inside(path, root) else None


class SceneLibrary:
    """The built-in scenes, the files of ``scenes_dir`` and the uploads in ``data_dir``/scenes (at most
    ``max_upload_bytes`` each; no ``data_dir``: no uploads)."""

    def __init__(self, scenes_dir: Path | None, data_dir: Path | None, max_upload_bytes: int) -> None:
        self.scenes_dir = scenes_dir.resolve() if scenes_dir is not None else None
        self.uploads_dir = (data_dir / UPLOADS_FOLDER).resolve() if data_dir is not None else None
        self.max_upload_bytes = max_upload_bytes
        #: The SHA-256 of every file hashed so far, kept across restarts; packed glTF files' apart.
        self._digests = DigestMemo(None if data_dir is None else data_dir / DIGESTS_FOLDER)
        self._packed = DigestMemo(None)
        self._remove_temporary_files()

    def _remove_temporary_files(self) -> None:
        """Uploads a crash interrupted: hidden temporary files, never listed."""
        if self.uploads_dir is not None and self.uploads_dir.is_dir():
            for leftover in self.uploads_dir.glob(TEMPORARY_PREFIX + "*"):
                leftover.unlink(missing_ok=True)

    def entries(self) -> list[SceneEntry]:
        """Every scene: built-in ones, then the library's and the uploads, each sorted by name."""
        found = [SceneEntry(BUILTIN_PREFIX + name, "builtin", 0) for name in BUILTIN_SCENES]
        if self.scenes_dir is not None:
            found += sorted(self._library_entries(self.scenes_dir), key=lambda entry: entry.name)
        if self.uploads_dir is not None and self.uploads_dir.is_dir():
            uploads = (_scene_file(self.uploads_dir, [child.name]) for child in self.uploads_dir.iterdir()
                       if not child.is_symlink())
            found += sorted((self._entry(UPLOAD_PREFIX + path.name, path) for path in uploads if path is not None),
                            key=lambda entry: entry.name)
        return found

    def describe(self) -> dict[str, Any]:
        """What the viewer's panel offers and says (``GET /api/library``): the library's ``folder``
        and how many ``library_scenes`` it holds, with a ``library_hint`` when none; whether
        ``uploads`` are on (``uploads_off``: why not and how to turn them on), their largest size
        (``max_upload_mb``) and the ``formats`` a file may have. Reads the folders: call it off the loop."""
        folder = self.scenes_dir
        count = 0 if folder is None else len(self._library_entries(folder))
        if folder is None:
            hint = "no scene library: start the coordinator with --scenes-dir DIR, or from a folder that holds scenes/"
        elif count == 0:
            formats = ", ".join(suffix.lstrip(".").upper() for suffix in SUPPORTED_SUFFIXES)
            hint = f"no scene files in {folder} yet: put {formats} files there (sub-folders too) to offer them here"
        else:
            hint = None
        return {"folder": None if folder is None else str(folder), "library_scenes": count, "library_hint": hint,
                "uploads": self.uploads_dir is not None,
                "uploads_off": UPLOADS_OFF if self.uploads_dir is None else None,
                "max_upload_mb": self.max_upload_bytes >> 20,
                "formats": [suffix.lstrip(".") for suffix in SUPPORTED_SUFFIXES]}

    def _library_entries(self, root: Path) -> list[SceneEntry]:
        entries = []
        for folder, subfolders, files in os.walk(root):
            subfolders[:] = [name for name in subfolders if not name.startswith(".")]
            relative = Path(folder).relative_to(root).parts
            for name in files:
                path = _scene_file(root, [*relative, name])
                if path is not None:
                    entries.append(self._entry(LIBRARY_PREFIX + "/".join([*relative, name]), path))
        return entries

    @staticmethod
    def _entry(name: str, path: Path) -> SceneEntry:
        return SceneEntry(name, scene_format(path), path.stat().st_size, path)

    def find(self, name: str) -> SceneEntry:
        """The scene called ``name``; raises :class:`UnknownScene` for any name :meth:`entries` lacks."""
        if name.startswith(BUILTIN_PREFIX) and name[len(BUILTIN_PREFIX):] in BUILTIN_SCENES:
            return SceneEntry(name, "builtin", 0)
        path = None
        if name.startswith(LIBRARY_PREFIX) and self.scenes_dir is not None:
            path = _scene_file(self.scenes_dir, name[len(LIBRARY_PREFIX):].split("/"))
        elif name.startswith(UPLOAD_PREFIX) and self.uploads_dir is not None and "/" not in name[len(UPLOAD_PREFIX):]:
            path = _scene_file(self.uploads_dir, [name[len(UPLOAD_PREFIX):]])
            if path is not None and path.is_symlink():
                path = None
        if path is None:
            raise UnknownScene(f"no scene named {name!r}")
        return self._entry(name, path)

    def content_hash(self, entry: SceneEntry) -> str:
        """SHA-256 (hex) of the bytes nodes fetch of a scene (its file's, or :meth:`packed_gltf`'s),
        computed once per (path, size, modification time, inode) of the file and remembered in
        ``data_dir``/digests across restarts (a packed glTF's in memory only: the files it refers to
        may change). Blocking: reads the whole file the first time."""
        assert entry.path is not None, "built-in scenes have no file"
        memo = self._packed if entry.format == "gltf" else self._digests
        known = memo.known(entry.path)
        if known is not None:
            return known
        packed = self.packed_gltf(entry)
        if packed is None:
            return memo.digest(entry.path)
        sha256 = hashlib.sha256(packed).hexdigest()
        memo.remember(entry.path, sha256)
        return sha256

    def packed_gltf(self, entry: SceneEntry) -> bytes | None:
        """A library ``.gltf`` whose buffers or images are separate files, made one self-contained
        file (:mod:`tessera.scene.gltf_pack`) for nodes that fetch it; None for any other scene,
        and for one that refers to a file outside the library or missing (then its file is
        served as it is: nodes that share the folder still load it). Blocking."""
        root = self.scenes_dir
        if entry.path is None or root is None or entry.format != "gltf" or not entry.name.startswith(LIBRARY_PREFIX):
            return None
        folder = entry.path.parent

        def read_file(uri: str) -> bytes:
            target = (folder / uri).resolve()
            if "://" in uri or os.path.isabs(uri) or not target.is_relative_to(root):
                raise GltfError(f"{uri!r} is not a file of the library")
            return target.read_bytes()

        try:
            return self_contained_gltf(entry.path.read_bytes(), read_file)
        except (GltfError, OSError) as exc:
            log.warning("%s is served as it is, without the files it refers to: %s", entry.name, exc)
            return None

    def begin_upload(self, filename: str) -> PendingUpload:
        """A temporary file to receive the upload ``filename`` into; raises :class:`SceneRefused`
        subclasses for a name or format it does not take, a name taken, or uploads unavailable."""
        if self.uploads_dir is None:
            raise UploadsUnavailable(UPLOADS_OFF)
        refusal = _part_refusal(filename)
        if refusal is not None:
            raise BadSceneName(f"{filename!r} is {refusal}; upload a plain file name")
        if not filename.lower().endswith(SUPPORTED_SUFFIXES):
            raise UnsupportedFormat(f"{filename!r}: unsupported file type; supported: {', '.join(SUPPORTED_SUFFIXES)}")
        final = self.uploads_dir / filename
        if final.exists() or final.is_symlink():
            raise SceneExists(f"a scene named {UPLOAD_PREFIX + filename!r} exists already")
        temporary = self.uploads_dir / f"{TEMPORARY_PREFIX}{secrets.token_hex(8)}-{filename}"
        try:
            self.uploads_dir.mkdir(parents=True, exist_ok=True)
            file = temporary.open("xb")
        except OSError as exc:
            raise UploadsUnavailable(f"cannot write uploads to {self.uploads_dir}: {exc.strerror or exc}") from None
        return PendingUpload(self, UPLOAD_PREFIX + filename, final, temporary, file)

    def too_large(self) -> UploadTooLarge:
        return UploadTooLarge(f"upload over the limit of {self.max_upload_bytes / (1 << 20):g} MiB (--max-upload-mb)")

    def remember_hash(self, path: Path, sha256: str) -> None:
        self._digests.remember(path, sha256)


class PendingUpload:
    """An upload on its way: a hidden temporary file beside its final place, counted and hashed as
    it is written: :meth:`write`, :meth:`finish`, then a check of :attr:`temporary`
    (:mod:`server.upload_check`), :meth:`commit`; :meth:`close` in any case (it removes the
    temporary file if still there)."""

    def __init__(self, library: SceneLibrary, name: str, final: Path, temporary: Path, file: BinaryIO) -> None:
        self.library = library
        self.name = name
        self.final = final
        self.temporary = temporary
        self.file = file
        self.size = 0
        self.digest = hashlib.sha256()

    def write(self, data: bytes) -> None:
        """Append ``data``; raises :class:`UploadTooLarge` past the limit, :class:`UploadsUnavailable`
        when the disk refuses (then nothing is kept)."""
        self.size += len(data)
        if self.size > self.library.max_upload_bytes:
            raise self.library.too_large()
        try:
            self.file.write(data)
        except OSError as exc:
            raise UploadsUnavailable(f"cannot write {self.name!r}: {exc.strerror or exc}") from None
        self.digest.update(data)

    def finish(self) -> None:
        """Flush the bytes to disk and close the file (blocking)."""
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
        except OSError as exc:
            raise UploadsUnavailable(f"cannot write {self.name!r}: {exc.strerror or exc}") from None
        finally:
            self.file.close()

    def commit(self) -> SceneEntry:
        """Put the finished file under its name (blocking); :class:`SceneExists` if another upload
        took the name meanwhile (then nothing is kept)."""
        try:
            os.link(self.temporary, self.final)
        except FileExistsError:
            raise SceneExists(f"a scene named {self.name!r} exists already") from None
        except OSError as exc:
            raise UploadsUnavailable(f"cannot store {self.name!r}: {exc.strerror or exc}") from None
        finally:
            self.temporary.unlink(missing_ok=True)
        folder = os.open(self.final.parent, os.O_RDONLY)
        try:
            os.fsync(folder)
        finally:
            os.close(folder)
        self.library.remember_hash(self.final, self.digest.hexdigest())
        return SceneEntry(self.name, scene_format(self.final), self.size, self.final)

    def close(self) -> None:
        self.file.close()
        self.temporary.unlink(missing_ok=True)


def check_scene_file(path: Path, name: str) -> int:
    """The triangles of the scene file at ``path``, loaded the way a render node loads it, in this
    process (the coordinator runs it in a child process with capped memory: :mod:`server.upload_check`);
    raises :class:`NotAScene` with the loader's reason (the file called ``name`` in it). A glTF must carry
    its buffers and images inside (GLB chunk or ``data:`` URIs): an upload has no files beside it, and
    a relative URI could reach any file of the coordinator's host."""
    try:
        if path.suffix.lower() in GLTF_SUFFIXES:
            _refuse_external_uris(path.read_bytes())
        if is_point_file(path):     # a point cloud: its points parse (issue 36); it has no triangles
            read_points(path)
            return 0
        return load_scene(str(path)).triangle_count
    except (SceneError, GltfError) as exc:
        raise NotAScene(str(exc).replace(str(path), name)) from None


def _refuse_external_uris(data: bytes) -> None:
    def refuse(uri: str) -> bytes:
        raise GltfError(f"buffer {uri[:80]!r} is a separate file: upload a .glb or a .gltf with data: URIs")

    document = read_document(data, refuse).json
    for image in document.get("images", []):
        uri = image.get("uri") if isinstance(image, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:"):
            raise GltfError(f"image {uri[:80]!r} is a separate file: upload a .glb or a .gltf with data: URIs")
