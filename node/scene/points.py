"""Point clouds made ready to draw (issue 36): a file's points (:mod:`node.scene.point_files`)
ingested once per content hash into an octree whose coarse levels come first, stored as a scene
cache entry (:func:`node.scene.cache.write_arrays`) and mapped back (:class:`PointCloud`). No GL here.

**Levels** (PotreeConverter's idea, vectorised): the cloud's cube is divided into a grid of side
2^ℓ at each sampling level ℓ; a point's level is the coarsest ℓ at which it is the first point of
its cell in Morton order (the codes XORed with a fixed mask, so that the chosen corner varies by
level). Levels 0…ℓ together then hold exactly one point per occupied level-ℓ cell: each level is
a subsample of the one below, and any prefix of the levels is an even picture of the cloud. One sort
of the Morton codes (with each point's number packed in their low bits: numpy's SIMD sort of
plain uint64, several times faster than an argsort) gives every level at once — a point's level
follows from the highest bit in which its code differs from the one before it.

**Nodes**: the points of level ℓ ≥ :data:`NODE_GRID_BITS` in the cell of depth d = ℓ − NODE_GRID_BITS
form a node of depth d (the root holds levels 0…NODE_GRID_BITS): a node holds one point per cell of
a 2^7 grid over its cube, about 16k points on a surface, like Potree's nodes. The points past the
finest level the codes resolve (several in one finest cell) go to the deepest nodes. Nodes are
stored in hierarchy order (depth, then Morton order), each node's points contiguous, with its
parent, depth, the octant of its parent it lies in, its cube's centre, the box around its own points
and the box around its subtree (:class:`tessera.points.budget.PointTree`).

**Survey coordinates**: positions are stored as float32 relative to the cloud's centre (float64
in the table), so millimetres survive UTM eastings of 10⁶ m; the renderer folds the centre into
its matrices in float64 (:mod:`node.gl.point_renderer`).

**Colours**: RGB when the file has it, else its intensity through a colour map (1st…99th percentile
over the map), else the height through it; RGBA uint8 (alpha unused, for alignment: 16 bytes a point).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from node.scene import compiled
from node.scene.cache import Progress
from node.scene.chunks import PrimitiveGroups
from node.scene.mesh import SceneError
from node.scene.pages import is_mapped
from node.scene.point_files import PointArrays
from tessera.points.budget import PointTree
from tessera.scene.graph import ObjectGraph, SceneObject

#: The layout of a point cloud's cache entry: an entry of another is built again, never read.
POINTS_FORMAT = 2
#: A node's sampling grid: 2^NODE_GRID_BITS cells a side.
NODE_GRID_BITS = 7
#: Finest sampling level the codes resolve at most (3 bits a level; the points' numbers take the rest of 64).
MAX_LEVEL = 17
#: The XOR mask of the Morton codes (any fixed pattern: the corner chosen in each cell varies by level).
CODE_MASK = 0x5A3C_96E1_B2D4_8F17
#: A colour map for intensity and height: (K, 3) uint8 stops from dark blue through green to yellow
#: (viridis's ends and middle), interpolated over 256 entries.
COLOR_MAP_STOPS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64)
#: A node whose subtree holds at most this many points is a leaf holding them all.
LEAF_POINTS = 16384
#: Most points of a run a tile culls as one (:class:`PointChunks`).
CHUNK_POINTS = 4096
#: Most groups a cloud reports to the coordinator (its shallowest nodes, deeper ones merged into them).
MAX_POINT_GROUPS = 2048


def color_map(values: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours of ``values`` (N,) through the map, its 1st…99th percentile spread over it."""
    values = np.asarray(values, np.float64)
    lo, hi = np.percentile(values, [1.0, 99.0]) if values.size else (0.0, 1.0)
    table = np.stack([np.interp(np.linspace(0.0, 1.0, 256), np.linspace(0.0, 1.0, len(COLOR_MAP_STOPS)),
                                COLOR_MAP_STOPS[:, c]) for c in range(3)], axis=1).round().astype(np.uint8)
    index = np.clip((values - lo) / max(hi - lo, 1e-12) * 255.0, 0.0, 255.0).astype(np.intp)
    return table[index]


@dataclass(frozen=True, eq=False)
class PointChunks:
    """C runs of a node's points (points within a node lie in Morton order, so a run is a small
    region of it): ``first`` (C + 1,) int64 point offsets, ``node`` (C,) int64 and ``boxes`` (C, 2, 3)
    float32 around its points (relative to the cloud's centre)."""

    first: np.ndarray
    node: np.ndarray
    boxes: np.ndarray

    @classmethod
    def of(cls, first: np.ndarray, positions: np.ndarray) -> PointChunks:
        """The runs of nodes whose points start at ``first`` (M + 1,) over ``positions`` (N, 3)."""
        counts = np.diff(first)
        per_node = -(-counts // CHUNK_POINTS)
        node = np.repeat(np.arange(len(counts)), per_node)
        within = np.arange(len(node)) - np.repeat(np.cumsum(per_node) - per_node, per_node)
        starts = first[node] + within * CHUNK_POINTS
        boxes = np.empty((len(starts), 2, 3), np.float32)
        if len(starts):
            boxes[:, 0] = np.minimum.reduceat(positions, starts, axis=0)
            boxes[:, 1] = np.maximum.reduceat(positions, starts, axis=0)
        return cls(np.append(starts, first[-1]).astype(np.int64), node.astype(np.int64), boxes)


@dataclass(frozen=True, eq=False)
class PointNodes:
    """The octree's M nodes (module docstring): ``first`` (M + 1,) int64 point offsets, ``tree`` (the
    hierarchy and subtree boxes, relative to the cloud's centre), ``own_boxes`` (M, 2, 3) float32
    boxes around each node's own points and ``centres`` (M, 3) float32 its cube's centre (relative),
    ``spacing`` the root's point spacing (its grid's cell side) and ``cube`` its cube's side; its
    ``chunks``: the points in runs of at most :data:`CHUNK_POINTS` within a node, which tiles cull."""

    first: np.ndarray
    tree: PointTree
    own_boxes: np.ndarray
    centres: np.ndarray
    spacing: float
    cube: float
    chunks: PointChunks

    @property
    def count(self) -> int:
        return self.tree.node_count


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A point cloud ready to draw: ``positions`` (N, 3) float32 relative to ``centre`` (3,) float64
    world, ``colors`` (N, 4) uint8 RGBA, in node order; ``nodes``; world ``bounds`` (2, 3) float64;
    one object named after the file. ``share``: (index, weights) of a sort-last share (None: the
    whole cloud; a share holds its nodes' points, the other nodes empty, the whole tree)."""

    name: str
    positions: np.ndarray
    colors: np.ndarray
    centre: np.ndarray
    nodes: PointNodes
    bounds: np.ndarray
    objects: ObjectGraph
    animations: tuple[()] = ()
    share: tuple[int, tuple[float, ...]] | None = None

    @property
    def point_count(self) -> int:
        return int(self.positions.shape[0])

    @property
    def triangle_count(self) -> int:
        return 0

    @property
    def world_tree(self) -> PointTree:
        """The tree with its boxes in world coordinates (float64), as the budget chooses from it."""
        tree = self.nodes.tree
        return dataclasses.replace(tree, boxes=tree.boxes + self.centre)

    @property
    def groups(self) -> PrimitiveGroups:
        """The shallowest nodes as primitive groups (world subtree boxes, their subtree's points), at
        most :data:`MAX_POINT_GROUPS` (seed 003's DPBP: the coordinator's predictions)."""
        tree = self.world_tree
        subtree = _subtree_counts(tree)
        depth = int(tree.depths.max(initial=0))
        while depth > 0 and int((tree.depths <= depth).sum()) > MAX_POINT_GROUPS:
            depth -= 1
        keep = np.flatnonzero(tree.depths <= depth)
        counts = np.where(tree.depths[keep] == depth, subtree[keep], tree.counts[keep])
        boxes = tree.boxes[keep].reshape(-1, 6)
        return PrimitiveGroups(boxes, counts.astype(np.int64), np.zeros(len(keep), np.int64), keep.astype(np.int64))

    @property
    def gpu_bytes(self) -> int:
        return self.positions.nbytes + self.colors.nbytes + self.nodes.count * 24

    @property
    def nbytes(self) -> int:
        """Bytes held in memory (mapped arrays not counted: their pages leave once uploaded)."""
        return sum(a.nbytes for a in (self.positions, self.colors) if not is_mapped(a))


def _subtree_counts(tree: PointTree) -> np.ndarray:
    """(M,) int64 points of each node's subtree."""
    totals = tree.counts.astype(np.int64).copy()
    for ids in reversed(tree.by_depth()[1:]):
        np.add.at(totals, tree.parents[ids], totals[ids])
    return totals


def _spread_bits(values: np.ndarray) -> np.ndarray:
    """(N,) uint64: the low 21 bits of ``values`` spread to every third bit (Morton interleave), by
    a table of 7 bits at a time (three gathers: several times fewer passes than shifts and masks)."""
    x = values.astype(np.uint32)
    spread = _SPREAD_TABLE[x & 0x7F]
    spread |= _SPREAD_TABLE[(x >> 7) & 0x7F] << np.uint64(21)
    spread |= _SPREAD_TABLE[(x >> 14) & 0x7F] << np.uint64(42)
    return spread


def _spread_slow(values: np.ndarray) -> np.ndarray:
    """:func:`_spread_bits` by shifts and masks (builds its table)."""
    x = values.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


_SPREAD_TABLE = _spread_slow(np.arange(128))


def build_octree(points: PointArrays, name: str, progress: Progress) -> PointCloud:
    """The octree of ``points`` (module docstring), the cloud named ``name``."""
    count = points.count
    if count == 0:
        raise SceneError(f"{name}: no points")
    started = time.perf_counter()
    world = points.positions
    finite = np.isfinite(world).all(axis=1) if not np.isfinite(world).all() else None
    if finite is not None:
        points = PointArrays(world[finite], *(None if a is None else a[finite]
                                              for a in (points.colors, points.intensity, points.normals)))
        world, count = points.positions, int(finite.sum())
        if count == 0:
            raise SceneError(f"{name}: no finite points")
    lo = np.array([world[:, axis].min() for axis in range(3)])      # column by column: 5x a reduction over axis 0
    hi = np.array([world[:, axis].max() for axis in range(3)])
    centre = (lo + hi) / 2.0
    cube = max(float((hi - lo).max()), 1e-9) * (1.0 + 1e-9)
    index_bits = max(int(count - 1).bit_length(), 1)
    levels = min((64 - index_bits) // 3, MAX_LEVEL)
    cells = 1 << levels
    flip = CODE_MASK & ((1 << (3 * levels)) - 1)
    progress(0.4, f"sorting {count} points ({time.perf_counter() - started:.1f} s)")
    if compiled.available(count):     # numba's one pass and radix sort: the same keys, a third of the CPU
        keys = compiled.sorted_point_keys(world, lo, cells / cube, levels, flip, index_bits)
    else:
        code = np.zeros(count, np.uint64)
        for axis in range(3):
            cell = (world[:, axis] - lo[axis]) * (cells / cube)
            np.clip(cell, 0, cells - 1, out=cell)      # non-negative: the cast floors
            code |= _spread_bits(cell.astype(np.uint32)) << np.uint64(axis)
        code ^= np.uint64(flip)
        keys = np.sort((code << np.uint64(index_bits)) | np.arange(count, dtype=np.uint64))
        del code
    order = (keys & np.uint64((1 << index_bits) - 1)).astype(np.int64)
    code = keys >> np.uint64(index_bits)
    del keys
    # A point's level: 0 for the first; else from the highest bit its code differs in from the previous.
    differ = np.zeros(count, np.uint64)
    np.bitwise_xor(code[1:], code[:-1], out=differ[1:])
    bit_length = np.frexp(differ.astype(np.float64))[1]
    level = np.where(differ > 0, levels + 1 - (bit_length + 2) // 3, levels + 1)
    level[0] = 0
    del differ, bit_length
    depth = np.maximum(level - NODE_GRID_BITS, 0).astype(np.uint8)
    del level
    progress(0.55, f"grouping {count} points into nodes ({time.perf_counter() - started:.1f} s)")
    by_depth = np.argsort(depth, kind="stable")
    order = order[by_depth]
    code, depth = code[by_depth], depth[by_depth].astype(np.int64)
    del by_depth
    node_key = (depth << 58) | (code >> (3 * (levels - depth)).astype(np.uint64)).astype(np.int64)
    starts = np.flatnonzero(np.concatenate(([True], node_key[1:] != node_key[:-1])))
    keys_found = node_key[starts]
    del node_key, code
    runs = np.diff(np.append(starts, count))
    keys_all = _with_ancestors(keys_found)
    run_node = np.searchsorted(keys_all, keys_found)
    counts_all = np.bincount(run_node, weights=runs, minlength=len(keys_all)).astype(np.int64)
    keys, final = _collapsed(keys_all, counts_all)
    if len(keys) < len(keys_all):   # points of collapsed subtrees gathered into their leaf: whole runs moved
        order = order[_runs_gathered(final[run_node], starts, runs)]
    counts = np.bincount(final[run_node], weights=runs, minlength=len(keys)).astype(np.int64)
    first = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
    progress(0.7, f"{len(keys)} nodes; writing colours ({time.perf_counter() - started:.1f} s)")
    relative = np.empty((count, 3), np.float32)
    for axis in range(3):     # a column at a time: no (N, 3) float64 temporaries
        relative[:, axis] = world[order, axis] - centre[axis]
    colors = np.empty((count, 4), np.uint8)
    colors[:, 3] = 255
    if points.colors is not None:
        colors[:, :3] = points.colors[order]
    elif points.intensity is not None:
        colors[:, :3] = color_map(points.intensity[order])
    else:
        colors[:, :3] = color_map(world[order, 2])
    tree_nodes = _node_geometry(keys, counts, first, relative, lo - centre, cube, levels)
    bounds = np.stack([lo, hi])
    return PointCloud(name, relative, colors, centre, tree_nodes, bounds,
                      ObjectGraph([SceneObject(Path(name).stem or name, bounds=bounds)]))


def _runs_gathered(run_target: np.ndarray, starts: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """(N,) int64 the permutation that orders N points, in runs of ``runs`` points starting at
    ``starts``, by their run's ``run_target`` (stable: runs of one target keep their order, points
    within a run too) — the runs moved whole, no sort of the points."""
    moved = np.argsort(run_target, kind="stable")
    lengths = runs[moved]
    placed = np.cumsum(lengths) - lengths
    return np.repeat(starts[moved] - placed, lengths) + np.arange(int(lengths.sum()), dtype=np.int64)


def _with_ancestors(keys: np.ndarray) -> np.ndarray:
    """(K',) int64 sorted node keys (depth << 58 | cell code at that depth) of ``keys`` and all their ancestors."""
    found = [keys]
    level = keys
    while level.size:
        depth = level >> 58
        level = level[depth > 0]
        depth = depth[depth > 0]
        level = np.unique(((depth - 1) << 58) | ((level & ((1 << 58) - 1)) >> 3))
        found.append(level)
    return np.unique(np.concatenate(found))


def _parents(keys: np.ndarray) -> np.ndarray:
    """(M,) int64 the parent of each of the sorted node ``keys`` (−1 for the root); every parent is among them."""
    depths = keys >> 58
    parent_keys = ((depths - 1) << 58) | ((keys & ((1 << 58) - 1)) >> 3)
    return np.where(depths > 0, np.searchsorted(keys, parent_keys), -1).astype(np.int64)


def _collapsed(keys: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nodes whose subtree holds at most :data:`LEAF_POINTS` points, under a parent holding more,
    made leaves holding their subtree's points (Potree's leaves: small nodes cost more to choose
    and draw than they save): (kept keys (K,), for each of ``keys`` (M,) the kept node (index) its
    points go to)."""
    parents = _parents(keys)
    depths = keys >> 58
    bounds = np.searchsorted(depths, np.arange(int(depths.max(initial=0)) + 2))
    subtree = counts.copy()
    for depth in range(len(bounds) - 2, 0, -1):
        ids = np.arange(bounds[depth], bounds[depth + 1])
        np.add.at(subtree, parents[ids], subtree[ids])
    target = np.full(len(keys), -1, np.int64)
    for depth in range(len(bounds) - 1):
        ids = np.arange(bounds[depth], bounds[depth + 1])
        above = target[parents[ids]] if depth else np.full(len(ids), -1, np.int64)
        target[ids] = np.where(above >= 0, above, np.where(subtree[ids] <= LEAF_POINTS, ids, -1))
    kept = (target < 0) | (target == np.arange(len(keys)))
    rank = np.cumsum(kept) - 1
    return keys[kept], np.where(kept, rank, rank[np.maximum(target, 0)])


def _node_geometry(keys: np.ndarray, counts: np.ndarray, first: np.ndarray, relative: np.ndarray,
                   origin: np.ndarray, cube: float, levels: int) -> PointNodes:
    """The :class:`PointNodes` of nodes ``keys`` with ``counts`` and offsets ``first`` over ``relative``
    points, the cube of side ``cube`` at ``origin`` (relative), codes of ``levels`` levels."""
    depths = keys >> 58
    cells = keys & ((1 << 58) - 1)
    parents = _parents(keys)
    unmasked = cells ^ ((CODE_MASK & ((1 << (3 * levels)) - 1)) >> (3 * (levels - depths)))
    coords = np.stack([_compact_bits(unmasked >> axis) for axis in range(3)], axis=1).astype(np.float64)
    side = cube / np.exp2(depths.astype(np.float64))
    centres = origin + (coords + 0.5) * side[:, None]
    octants = np.zeros(len(keys), np.int64)
    child = depths > 0
    octants[child] = ((centres[child] > centres[parents[child]]) * np.array([1, 2, 4])).sum(axis=1)
    own = np.empty((len(keys), 2, 3), np.float64)
    nonempty = counts > 0
    starts = first[:-1][nonempty]
    own[nonempty, 0] = np.minimum.reduceat(relative, starts, axis=0)
    own[nonempty, 1] = np.maximum.reduceat(relative, starts, axis=0)
    own[~nonempty, 0], own[~nonempty, 1] = np.inf, -np.inf
    subtree = own.copy()
    tree = PointTree(subtree, counts, parents, depths.astype(np.int64), octants)
    for ids in reversed(tree.by_depth()[1:]):
        np.minimum.at(subtree[:, 0], parents[ids], subtree[ids, 0])
        np.maximum.at(subtree[:, 1], parents[ids], subtree[ids, 1])
    own[~nonempty] = subtree[~nonempty]
    return PointNodes(first, tree, own.astype(np.float32), centres.astype(np.float32),
                      cube / (1 << NODE_GRID_BITS), cube, PointChunks.of(first, relative))


def _compact_bits(values: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_spread_bits`: every third bit of ``values`` gathered (int64)."""
    x = values.astype(np.uint64) & np.uint64(0x1249249249249249)
    for shift, mask in ((2, 0x10C30C30C30C30C3), (4, 0x100F00F00F00F00F), (8, 0x1F0000FF0000FF),
                        (16, 0x1F00000000FFFF), (32, 0x1FFFFF)):
        x = (x | (x >> np.uint64(shift))) & np.uint64(mask)
    return x.astype(np.int64)
