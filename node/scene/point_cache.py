"""Point clouds in the scene cache (issue 36): a cloud ingested once per content hash (read,
octree built: :mod:`node.scene.points`) into an entry of its own layout, written and checked as
mesh entries are (:func:`node.scene.cache.write_arrays`: atomic, CRC per block, mapped back), and
sort-last shares of it read from that entry by the byte ranges of their nodes only. No GL here.

An entry holds ``positions`` (N, 3) float32 relative to the centre, ``colors`` (N, 4) uint8, and the
node table: ``node_first`` (M + 1,), ``node_counts``, ``node_parents``, ``node_depths``,
``node_octants`` (M,) int64, ``node_boxes`` (M, 2, 3) float64 subtree boxes, ``node_own_boxes`` and
``node_centres`` float32; its table the centre, bounds, spacing and cube, the source and the share.
A share keeps the whole node table (every node chooses the frame's points from the whole tree, so
that all shares choose alike) with ``node_first`` over its own points: the nodes of other shares
hold none there.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from node.scene.cache import BLOCK_BYTES, CacheError, Progress, block_crc, read_arrays, read_table, write_arrays
from node.scene.cache_folder import CacheFolder, checked_entry, share_name
from node.scene.mesh import SceneError
from node.scene.point_files import read_points
from node.scene.points import POINTS_FORMAT, PointChunks, PointCloud, PointNodes, build_octree
from tessera.decomposition.data_partition import split_chunks
from tessera.points.budget import PointTree
from tessera.scene.graph import ObjectGraph
from tessera.wire.messages import ShareSpec

#: The format of point cloud entries' tables and files (the mesh entries' :data:`node.scene.cache.CACHE_FORMAT`
#: went on to 2 with nothing a point cloud holds changed).
POINTS_ENTRY_FORMAT = 1


def points_entry_name(sha256: str) -> str:
    """The name of the entry of the point cloud file whose SHA-256 is ``sha256``."""
    return f"{sha256}-points{POINTS_FORMAT}-v{POINTS_ENTRY_FORMAT}"


def is_points_entry(directory: Path) -> bool:
    """Whether the entry ``directory`` holds a point cloud."""
    try:
        return read_table(directory, POINTS_ENTRY_FORMAT).get("kind") == "points"
    except CacheError:
        return False


def write_points_entry(directory: Path, cloud: PointCloud, source: Mapping[str, Any]) -> int:
    """Write ``cloud`` (whole or a share) as the entry ``directory``; returns its bytes."""
    nodes, tree = cloud.nodes, cloud.nodes.tree
    arrays = {"positions": np.ascontiguousarray(cloud.positions), "colors": np.ascontiguousarray(cloud.colors),
              "node_first": nodes.first, "node_counts": tree.counts, "node_parents": tree.parents,
              "node_depths": tree.depths, "node_octants": tree.octants, "node_boxes": tree.boxes,
              "node_own_boxes": nodes.own_boxes, "node_centres": nodes.centres, "chunk_first": nodes.chunks.first,
              "chunk_node": nodes.chunks.node, "chunk_boxes": nodes.chunks.boxes}
    table = {"format": POINTS_ENTRY_FORMAT, "kind": "points", "points_format": POINTS_FORMAT, "source": dict(source),
             "share": None if cloud.share is None else {"index": cloud.share[0], "weights": list(cloud.share[1])},
             "centre": cloud.centre.tolist(), "bounds": cloud.bounds.tolist(), "spacing": nodes.spacing,
             "cube": nodes.cube, "points": cloud.point_count, "objects": cloud.objects.to_json(),
             "vertex_bytes": int(cloud.positions.nbytes + cloud.colors.nbytes), "index_bytes": 0}
    return write_arrays(directory, arrays, table)


def open_points_entry(directory: Path, name: str, verify: bool = True) -> PointCloud:
    """The point cloud of the entry ``directory``, named ``name``, mapped; ``verify``: check the CRCs
    first. Raises CacheError."""
    table, arrays = read_arrays(directory, verify, POINTS_ENTRY_FORMAT)
    try:
        if table.get("kind") != "points" or table.get("points_format") != POINTS_FORMAT:
            raise CacheError(f"{directory.name}: not a point cloud entry of format {POINTS_FORMAT}")
        tree = PointTree(np.asarray(arrays["node_boxes"], np.float64), np.array(arrays["node_counts"], np.int64),
                         np.array(arrays["node_parents"], np.int64), np.array(arrays["node_depths"], np.int64),
                         np.array(arrays["node_octants"], np.int64))
        chunks = PointChunks(np.array(arrays["chunk_first"], np.int64), np.array(arrays["chunk_node"], np.int64),
                             np.array(arrays["chunk_boxes"], np.float32))
        nodes = PointNodes(np.array(arrays["node_first"], np.int64), tree, np.array(arrays["node_own_boxes"]),
                           np.array(arrays["node_centres"]), float(table["spacing"]), float(table["cube"]), chunks)
        share = table["share"]
        return PointCloud(name, arrays["positions"], arrays["colors"], np.asarray(table["centre"], np.float64), nodes,
                          np.asarray(table["bounds"], np.float64), ObjectGraph.from_json(table["objects"]),
                          share=None if share is None else (int(share["index"]),
                                                            tuple(float(w) for w in share["weights"])))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CacheError(f"{directory.name}: inconsistent table ({type(exc).__name__}: {exc})") from None


def checked_prefixes(directory: Path) -> Iterator[int]:
    """Check the CRCs of the point cloud entry ``directory`` in the order a node uploads it (raises
    CacheError at the first that fails): every array but the positions and colours (the node
    table), then those two a block at a time, the one covering fewer points first; after each
    block, yields how many of the first points have both passed (last: every point). A node draws
    a point once it passed (:class:`node.gl.point_renderer.PointRenderer`'s ``checked``)."""
    table, arrays = read_arrays(directory, False, POINTS_ENTRY_FORMAT)
    try:
        for name, array in arrays.items():
            crcs = list(table["files"][name]["crc32"])
            if name not in ("positions", "colors") and [block_crc(array, b) for b in range(len(crcs))] != crcs:
                raise CacheError(f"{directory.name}: {name}.npy fails its checksum (corrupt)")
        positions, colors = arrays["positions"], arrays["colors"]
        wanted = {name: list(table["files"][name]["crc32"]) for name in ("positions", "colors")}
    except (KeyError, TypeError) as exc:
        raise CacheError(f"{directory.name}: inconsistent table ({type(exc).__name__}: {exc})") from None
    count = int(positions.shape[0])
    for name, array in (("positions", positions), ("colors", colors)):
        if len(wanted[name]) != max(-(-array.nbytes // BLOCK_BYTES), 1):
            raise CacheError(f"{directory.name}: {name}.npy has {len(wanted[name])} checksums for {array.nbytes} bytes")
    done = {"positions": 0, "colors": 0}

    def covered(name: str) -> int:
        """The first points whose rows in ``name`` lie in the blocks checked."""
        array = positions if name == "positions" else colors
        whole = done[name] >= len(wanted[name])
        return count if whole else min(count, done[name] * BLOCK_BYTES // max(array.strides[0], 1))

    while left := [name for name in done if done[name] < len(wanted[name])]:
        name = min(left, key=covered)
        if block_crc(positions if name == "positions" else colors, done[name]) != wanted[name][done[name]]:
            raise CacheError(f"{directory.name}: {name}.npy fails its checksum (corrupt)")
        done[name] += 1
        yield min(covered("positions"), covered("colors"))


class PointCheck:
    """The check of a point cloud entry ``directory`` (:func:`checked_prefixes`), :meth:`run` in a
    thread of its own while others read how far it got: :attr:`points` (the first points that
    passed), :attr:`failed` (why it failed; None: it did not) and :meth:`wait` for more."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.points = 0
        self.failed: str | None = None
        self._changed = threading.Condition()

    def run(self) -> bool:
        """Check the entry, telling those who wait after each block; whether it passed."""
        try:
            for points in checked_prefixes(self.directory):
                with self._changed:
                    self.points = points
                    self._changed.notify_all()
        except (CacheError, OSError, ValueError) as exc:     # whatever stops it: those who wait are told
            with self._changed:
                self.failed = str(exc) or type(exc).__name__
                self._changed.notify_all()
            return False
        return True

    def wait(self, points: int, timeout: float | None = None) -> bool:
        """Whether the first ``points`` points passed, waiting up to ``timeout`` s (None: until they
        did or the check failed)."""
        with self._changed:
            self._changed.wait_for(lambda: self.points >= points or self.failed is not None, timeout)
            return self.points >= points


def share_nodes(cloud: PointCloud, weights: Sequence[float], index: int) -> np.ndarray:
    """(M,) bool: the nodes of share ``index`` of ``cloud`` over ``weights``: the octree's nodes split
    into spatially coherent shares by their own boxes and points
    (:func:`tessera.decomposition.data_partition.split_chunks`)."""
    nodes = cloud.nodes
    return split_chunks(nodes.own_boxes.astype(np.float64), nodes.tree.counts, weights) == index


def keep_point_share(cloud: PointCloud, weights: Sequence[float], index: int) -> PointCloud:
    """Share ``index`` of ``cloud`` over ``weights``: its nodes' points (read by their ranges), the
    whole node table. Raises SceneError when it holds no point."""
    keep = share_nodes(cloud, weights, index)
    first = cloud.nodes.first
    own = np.where(keep, np.diff(first), 0)
    if not own.any():
        raise SceneError(f"{cloud.name}: share {index} of {len(weights)} holds no point")
    ranges = [(int(first[i]), int(first[i + 1])) for i in np.flatnonzero(own)]
    positions = np.concatenate([cloud.positions[a:b] for a, b in ranges])
    colors = np.concatenate([cloud.colors[a:b] for a, b in ranges])
    first_kept = np.concatenate(([0], np.cumsum(own))).astype(np.int64)
    nodes = dataclasses.replace(cloud.nodes, first=first_kept, chunks=PointChunks.of(first_kept, positions))
    return dataclasses.replace(cloud, positions=positions, colors=colors, nodes=nodes,
                               share=(index, tuple(float(w) for w in weights)))


def load_points(path: Path, name: str, progress: Progress) -> PointCloud:
    """Read the point cloud file at ``path`` and build its octree (in memory), named ``name``."""
    progress(0.05, f"reading {path.name}")
    points = read_points(path)
    progress(0.3, f"read {points.count} points; building the octree")
    return build_octree(points, name, progress)


def cached_points(source: Path, share: ShareSpec | None, folder: CacheFolder, progress: Progress,
                  sha256: str | None = None) -> Path:
    """The checked entry of the point cloud ``source`` (its ``share`` only, when given) in ``folder``,
    built first if need be. Raises SceneError."""
    digest = sha256 or folder.content_hash(source, progress)
    origin = {"sha256": digest, "bytes": source.stat().st_size, "name": source.name}
    whole_name = points_entry_name(digest)

    def build_whole(directory: Path) -> int:
        cloud = load_points(source, source.name, progress)
        progress(0.8, f"writing the scene cache: {cloud.point_count} points in {cloud.nodes.count} nodes")
        return write_points_entry(directory, cloud, origin)

    def build_share(whole: Path, directory: Path) -> int:
        try:
            cloud = open_points_entry(whole, source.name, verify=False)
        except CacheError as exc:
            raise SceneError(f"{source.name}: {exc}") from None
        assert share is not None
        return write_points_entry(directory, keep_point_share(cloud, share.weights, share.index), origin)

    return checked_entry(folder, whole_name, build_whole,
                         None if share is None else (share_name(whole_name, share.weights, share.index), build_share),
                         lambda entry: open_points_entry(entry, source.name, verify=True), source, progress,
                         POINTS_ENTRY_FORMAT)

