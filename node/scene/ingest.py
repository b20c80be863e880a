"""A scene file made ready to draw once (issue 31): read, split into chunks, normals computed,
packed and written as a scene cache entry (:mod:`node.scene.cache`) in the cache folder
(:mod:`node.scene.cache_folder`), then opened by mapping it. Sort-last shares are entries of their
own, read from the whole scene's entry. Built-in scenes, and files when no cache folder is given, are
read into memory as before. No GL here.

An entry found in the folder is checked before it is handed on (every array's CRC-32; a share's
check covers the share): one that fails is removed and built again, so a torn or corrupt cache is
never drawn. One this process has just written is not read back.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from node.scene.cache import (
    CacheError,
    Progress,
    open_entry,
    read_arrays,
    read_table,
    remove_entry,
    share_chunks,
    write_arrays,
    write_entry,
    write_share,
)
from node.scene.cache_folder import REBUILDS, CacheFolder, checked_entry, entry_name, share_name
from node.scene.data import SceneData
from node.scene.loading import BUILTIN_PREFIX, SUPPORTED_SUFFIXES, load_scene
from node.scene.lod import (
    LOD_FORMAT,
    GroupLevels,
    LodTree,
    build_lod,
    closed_batches,
    group_levels,
    lod_name,
    read_lod,
    write_lod,
)
from node.scene.mesh import SceneError
from node.scene.packing import pack
from node.scene.point_cache import cached_points, is_points_entry, keep_point_share, load_points, open_points_entry
from node.scene.point_files import is_point_file
from node.scene.points import PointCloud
from node.scene.shares import keep_share
from tessera.wire.messages import ShareSpec

#: The format of the primitive groups' levels kept beside a levels entry (:func:`kept_group_levels`):
#: raise it when :func:`node.scene.lod.group_levels` changes what it gives.
GROUP_LEVELS_FORMAT = 1
#: The format of the entry keeping a whole scene's batches' closedness (:func:`whole_batches_closed`).
CLOSED_FORMAT = 1


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off within (as it was after): an ingest's arrays are freed
    by their counts, and the objects numba's import makes set off full collections (0.3 s of a
    24.8M-triangle PLY's ingest, holding the GIL) that find nothing to free."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def build_entry(source: Path, face_limit: int, sha256: str, progress: Progress,
                read_ahead: list[SceneData] | None = None) -> Callable[[Path], int]:
    """Read ``source`` and write its entry; the builder :meth:`CacheFolder.ensure` calls. Returns
    bytes. ``read_ahead``: the scene already read (taken from the list, so that it is not held after)."""
    def build(directory: Path) -> int:
        scene = read_ahead.pop() if read_ahead else load_scene(str(source), progress, face_limit)
        progress(0.8, f"writing the scene cache: {scene.triangle_count} triangles in {scene.chunks.chunk_count} chunks")
        return write_entry(directory, scene, pack(scene.batches),
                           {"sha256": sha256, "bytes": source.stat().st_size, "name": source.name})
    return build


def cached_scene(source: Path, face_limit: int, share: ShareSpec | None, folder: CacheFolder, progress: Progress,
                 sha256: str | None = None) -> Path:
    """The checked entry of ``source`` (its ``share`` only, when given) in ``folder``, built first if
    need be; ``sha256``: the file's digest when known. A file whose digest is neither given nor
    remembered is read while it is hashed (both take seconds for a big file; the hash runs on a thread
    of its own), under the folder's lock of its path. Raises SceneError."""
    digest = sha256 or folder.known_hash(source)
    with gc_paused():
        if digest is not None and (sha256 is not None or folder.existing(entry_name(digest, face_limit)) is not None):
            return _checked(source, face_limit, share, folder, progress, digest, None)
        with folder.reading(source, progress):
            digest = sha256 or folder.known_hash(source)   # another process may have read it while this one waited
            if digest is not None:
                return _checked(source, face_limit, share, folder, progress, digest, None)
            hashing = ThreadPoolExecutor(1)
            try:
                digest_later = hashing.submit(folder.content_hash, source, lambda fraction, message: None)
                read_ahead = [load_scene(str(source), progress, face_limit)]
                digest = digest_later.result()
            finally:
                hashing.shutdown(wait=False)
            return _checked(source, face_limit, share, folder, progress, digest, read_ahead)


def _checked(source: Path, face_limit: int, share: ShareSpec | None, folder: CacheFolder, progress: Progress,
             digest: str, read_ahead: list[SceneData] | None) -> Path:
    """:func:`cached_scene` once the digest is known."""
    whole_name = entry_name(digest, face_limit)
    origin = {"sha256": digest, "name": source.name}

    def build_share(whole: Path, directory: Path) -> int:
        try:
            scene = open_entry(whole, source.name, verify=False)
            assert share is not None
            return write_share(directory, scene, share.weights, share.index, origin)
        except CacheError as exc:
            raise SceneError(f"{source.name}: {exc}") from None

    return checked_entry(folder, whole_name, build_entry(source, face_limit, digest, progress, read_ahead),
                         None if share is None else (share_name(whole_name, share.weights, share.index), build_share),
                         lambda entry: open_entry(entry, source.name, verify=True), source, progress)


def read_scene(source: str, spec: str, face_limit: int, share: ShareSpec | None, progress: Progress,
               folder: CacheFolder | None = None, sha256: str | None = None) -> SceneData | PointCloud | Path:
    """``source`` (a path or ``builtin:NAME``; the scene is named ``spec``) made ready: the entry to
    open (:func:`open_cached`) for a file when ``folder`` is given, else the scene read into memory
    (only ``share`` kept). Point clouds (issue 36: LAS, LAZ, a PLY without faces) go their own way
    (:mod:`node.scene.point_cache`). Raises SceneError."""
    if not source.startswith(BUILTIN_PREFIX) and is_point_file(Path(source)):
        if folder is not None:
            return cached_points(Path(source), share, folder, progress, sha256)
        cloud = load_points(Path(source), spec, progress)
        return cloud if share is None else keep_point_share(cloud, share.weights, share.index)
    if folder is not None and not source.startswith(BUILTIN_PREFIX):
        path = Path(source)
        if not path.is_file() or path.suffix.lower() not in SUPPORTED_SUFFIXES:
            load_scene(source, progress, face_limit)   # raises SceneError with the usual reason
        return cached_scene(path, face_limit, share, folder, progress, sha256)
    scene = load_scene(source, progress, face_limit)
    if source != spec:
        scene = dataclasses.replace(scene, name=spec)
    if share is not None:
        progress(0.8, f"keeping share {share.index + 1} of {len(share.weights)}")
        scene = keep_share(scene, share.weights, share.index)
    return scene


def open_cached(read: SceneData | PointCloud | Path, spec: str) -> SceneData | PointCloud:
    """The scene :func:`read_scene` made ready: an entry opened (checked already) and named ``spec``."""
    if not isinstance(read, Path):
        return read
    try:
        return open_points_entry(read, spec, verify=False) if is_points_entry(read) else \
            open_entry(read, spec, verify=False)
    except CacheError as exc:
        raise SceneError(f"{spec}: {exc}") from None


def cached_levels(entry: Path, folder: CacheFolder, progress: Progress) -> Path | None:
    """The checked levels-of-detail entry of the scene cache entry ``entry`` in ``folder``, built
    first if need be (:mod:`node.scene.lod`); None when the scene has no batch big enough for levels.
    The levels of a sort-last share mark its batches closed as the whole scene's are
    (:func:`whole_batches_closed`)."""
    def build(directory: Path) -> int:
        try:
            scene = open_entry(entry, entry.name, verify=False)
            share = read_table(entry).get("share")
        except CacheError as exc:
            raise SceneError(f"{entry.name}: {exc}") from None
        tree = build_lod(scene, progress)
        if share is not None and tree.node_count:
            closed = whole_batches_closed(folder, entry.name, int(share["index"]), tuple(share["weights"]))
            if closed is not None and closed.size == tree.batch_closed.size:
                tree = dataclasses.replace(tree, batch_closed=closed)
        return write_lod(directory, tree)

    for attempt in range(REBUILDS + 1):
        levels = folder.ensure(lod_name(entry.name), build, progress, LOD_FORMAT)
        try:
            tree = read_lod(levels, verify=True)
        except CacheError as exc:
            remove_entry(levels)
            if attempt == REBUILDS:
                raise SceneError(f"{entry.name}: its levels of detail fail again after a rebuild ({exc})") from None
            continue
        return levels if tree.node_count else None
    raise AssertionError("unreachable")


def whole_batches_closed(folder: CacheFolder, share_entry: str, index: int,
                         weights: tuple[float, ...]) -> np.ndarray | None:
    """(B,) bool for the B batches of the entry ``share_entry`` (share ``index`` over ``weights``):
    whether the whole scene's batch each comes from bounds solids facing outwards
    (:func:`node.scene.lod.closed_batches`, worked out once and kept beside the whole scene's entry);
    None when the folder no longer holds that entry. A share of a closed solid is not closed by
    itself, but its back faces lie behind the solid's front faces all the same, which the other
    shares draw where this one does not: the layers merged by depth are the same without them."""
    whole_name = share_entry.removesuffix(share_name("", weights, index))
    found = folder.existing(whole_name) if whole_name != share_entry else None
    if found is None:
        return None
    try:
        whole = open_entry(found, whole_name, verify=False)
        kept = folder.ensure(f"{whole_name}-closed{CLOSED_FORMAT}", lambda directory: write_arrays(
            directory, {"closed": closed_batches(whole)}, {"format": CLOSED_FORMAT}), lambda fraction, message: None,
            CLOSED_FORMAT)
        closed = np.array(read_arrays(kept, True, CLOSED_FORMAT)[1]["closed"], bool)
    except (CacheError, KeyError):
        return None
    present = np.unique(whole.chunks.batch[share_chunks(whole, weights, index)])
    return closed[present] if closed.size == len(whole.batches) else None


def group_levels_name(levels: str) -> str:
    """The name of the entry keeping the primitive groups' levels of levels entry ``levels``."""
    return f"{levels}-groups{GROUP_LEVELS_FORMAT}"


def kept_group_levels(folder: CacheFolder, levels: Path, tree: LodTree, scene: SceneData) -> GroupLevels:
    """:func:`node.scene.lod.group_levels` of ``tree`` (the levels entry ``levels`` of ``folder``) over
    ``scene``'s primitive groups: read from the entry kept beside the levels when it is there and
    passes its check, else worked out and kept (0.37 CPU-s for the 24.8M-triangle model's 512 groups
    over 441k chunks, on the way to a node's first frame after a restart)."""
    name = group_levels_name(levels.name)
    found = folder.existing(name, GROUP_LEVELS_FORMAT)
    if found is not None:
        try:
            _, arrays = read_arrays(found, True, GROUP_LEVELS_FORMAT)
            return np.array(arrays["errors"]), np.array(arrays["triangles"]), np.array(arrays["boxes"])
        except (CacheError, KeyError):
            remove_entry(found)
    errors, triangles, boxes = group_levels(tree, scene.groups.chunk_starts, scene.chunks.face_counts,
                                            scene.chunks.boxes)
    with contextlib.suppress(OSError):   # not kept (a full disk, say): worked out again next time
        folder.ensure(name, lambda directory: write_arrays(
            directory, {"errors": errors, "triangles": triangles, "boxes": boxes}, {"format": GROUP_LEVELS_FORMAT}),
            lambda fraction, message: None, GROUP_LEVELS_FORMAT)
    return errors, triangles, boxes
