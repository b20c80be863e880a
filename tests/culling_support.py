"""Test-only culling inputs, references and read-backs: real scan meshes and the split bunny, random
cameras and tiles, a tile's planes straight from its camera, the flat per-chunk box test the tree
traversal must match, merged index ranges, what a GPU culler kept, and the tile-sized viewport the
renderer does not use (it scissors a frame-sized framebuffer)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from node.culling.bvh import ChunkBVH, build_chunk_bvh, range_members
from node.culling.frustum import DEFAULT_PAD_PX, frustum_planes_from_matrix
from node.culling.gpu import GpuCuller
from node.scene.octree import ChunkSplit, octree_split
from tessera.geometry import Camera, Rect, view_projection
from tests.conftest import scene_path


def scan_mesh(relative: str) -> tuple[np.ndarray, np.ndarray]:
    """The real scene ``relative`` (under ../shared/scenes) as one mesh: positions (V, 3) float32 and
    faces (F, 3) uint32."""
    mesh = trimesh.load(scene_path(relative), force="mesh")
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.uint32)


def split_bunny() -> tuple[np.ndarray, np.ndarray, ChunkSplit, ChunkBVH, np.ndarray]:
    """The Stanford bunny split into chunks of at most 1024 faces: positions (V, 3) float32, faces
    (F, 3) uint32 in chunk order, the split, its chunk BVH, and its bounds (2, 3) float64."""
    positions, faces = scan_mesh("bunny/bun_zipper.ply")
    split = octree_split(positions, faces, face_limit=1024)
    bounds = np.array([positions.min(axis=0), positions.max(axis=0)], dtype=np.float64)
    return positions, split.reorder(faces), split, build_chunk_bvh(split.bounds), bounds


def random_cameras(bounds: np.ndarray, count: int, seed: int, nearest: float = 0.2,
                   widest_deg: float = 100.0) -> list[Camera]:
    """``count`` cameras around and inside the box ``bounds`` (2, 3), looking roughly at its centre:
    eyes ``nearest`` to 3 half-diagonals from it, random up vectors, vertical fields of view from 20°
    to ``widest_deg``."""
    rng = np.random.default_rng(seed)
    center = bounds.mean(axis=0)
    radius = float(np.linalg.norm(bounds[1] - bounds[0])) / 2.0
    cameras = []
    while len(cameras) < count:
        direction = rng.normal(size=3)
        eye = center + direction / np.linalg.norm(direction) * radius * rng.uniform(nearest, 3.0)
        target = center + rng.normal(scale=0.3 * radius, size=3)
        up = rng.normal(size=3)
        try:
            cameras.append(Camera(eye=tuple(eye.tolist()), target=tuple(target.tolist()), up=tuple(up.tolist()),
                                  fovy_deg=float(rng.uniform(20.0, widest_deg))))
        except ValueError:
            continue
    return cameras


def random_tiles(rng: np.random.Generator, count: int, size: tuple[int, int],
                 fixed: Sequence[Rect] = ()) -> list[Rect]:
    """``count`` tiles inside a ``size`` frame: a one-pixel tile, the ``fixed`` ones, then random rects."""
    width, height = size
    tiles = [Rect(int(rng.integers(0, width)), int(rng.integers(0, height)), 1, 1), *fixed]
    while len(tiles) < count:
        x, y = int(rng.integers(0, width - 1)), int(rng.integers(0, height - 1))
        tiles.append(Rect(x, y, int(rng.integers(1, width - x + 1)), int(rng.integers(1, height - y + 1))))
    return tiles


def tile_frustum_planes(camera: Camera, size: tuple[int, int], rect: Rect, bounds: np.ndarray,
                        pad_px: float = DEFAULT_PAD_PX) -> np.ndarray:
    """(6, 4) float64 world-space planes of ``rect``'s sub-frustum, from the same
    :func:`view_projection` (near/far from the scene ``bounds`` (2, 3)) that the renderer draws with."""
    return frustum_planes_from_matrix(view_projection(camera, size, bounds), size, rect, pad_px)


def classify_boxes(lo: np.ndarray, hi: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For boxes ``lo``/``hi`` (K, 3) and ``planes`` (P, 4): (outside, inside) (K, P) bool — the box
    lies wholly on the negative side (p-vertex test), or wholly on the positive side (n-vertex)."""
    center = (lo + hi) * 0.5
    extent = (hi - lo) * 0.5
    distance = center @ planes[:, :3].T + planes[:, 3]
    radius = extent @ np.abs(planes[:, :3]).T
    return distance + radius < 0.0, distance - radius >= 0.0


def cull_flat(bvh: ChunkBVH, planes: np.ndarray) -> np.ndarray:
    """(K,) int64 sorted chunks kept by testing every leaf box against ``planes`` (6, 4) at once —
    the same set as :func:`node.culling.bvh.cull`, without the hierarchy."""
    leaves = np.flatnonzero(bvh.left < 0)
    outside, _ = classify_boxes(bvh.lo[leaves], bvh.hi[leaves], np.asarray(planes, dtype=np.float64))
    return np.sort(bvh.first_chunk[leaves[~outside.any(axis=1)]]).astype(np.int64)


def merge_ranges(visible_chunks: np.ndarray, chunk_starts: np.ndarray,
                 chunk_ends: np.ndarray) -> list[tuple[int, int]]:
    """Fewest (start, count) ranges covering the ``visible_chunks`` (K,) ids, given each chunk's
    [start, end) (C,) — in faces or indices, the ranges come out in the same unit. Chunks whose
    ranges touch are merged into one draw."""
    chunks = np.unique(np.asarray(visible_chunks, dtype=np.int64))
    if chunks.size == 0:
        return []
    starts = np.asarray(chunk_starts, dtype=np.int64)[chunks]
    ends = np.asarray(chunk_ends, dtype=np.int64)[chunks]
    run_first = np.flatnonzero(np.concatenate(([True], starts[1:] != ends[:-1])))
    run_last = np.append(run_first[1:], chunks.size) - 1
    return [(int(s), int(e - s)) for s, e in zip(starts[run_first], ends[run_last], strict=True)]


def read_commands(culler: GpuCuller) -> np.ndarray:
    """(C, 5) uint32 commands of ``culler``'s last cull (a GPU→CPU read: waits for the GPU)."""
    return np.frombuffer(culler.commands.read(), np.uint32).reshape(-1, 5)


def read_visible_chunks(culler: GpuCuller) -> np.ndarray:
    """(K,) int64 sorted ids of the chunks ``culler``'s last cull kept (reads the commands back)."""
    commands = read_commands(culler)
    drawn = commands[commands[:, 0] > 0]
    index_starts = culler.gpu_bvh.index_starts
    first = np.searchsorted(index_starts, drawn[:, 2])
    end = np.searchsorted(index_starts, drawn[:, 2].astype(np.int64) + drawn[:, 0])
    return np.sort(range_members(first, end))


def read_input_nodes(culler: GpuCuller) -> np.ndarray:
    """(T,) uint32 sorted: the input cut ``culler``'s next cull starts from."""
    data = np.frombuffer(culler.inputs[0].read(), np.uint32)
    return np.sort(data[4:4 + data[3]])


def tile_viewport(rect: Rect, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """GL viewport (x, y, w, h) that draws the full ``size`` frame shifted so ``rect`` lands on a
    ``rect.w``×``rect.h`` framebuffer."""
    width, height = size
    return (-rect.x, rect.y + rect.h - height, width, height)
