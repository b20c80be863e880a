"""The octree split's face passes compiled (issue 31: cold ingest of tens of millions of triangles a
second), with numba when it is installed: one loop over the faces where numpy takes several passes
and temporary arrays. Used for meshes of at least :data:`COMPILED_FACES` faces; smaller ones, and
every mesh where numba is missing, take the numpy passes (:mod:`node.scene.octree`,
:mod:`node.scene.face_pass`), which give the same arrays. No GL here.

- :func:`sorted_faces`: the faces renumbered to the new vertex order and sorted by their lowest
  vertex, then by number, as one counting sort (two linear passes on two threads, no keys sorted);
- :func:`sorted_vertices`: the vertices' Morton codes and sort keys (code above number) made in one
  pass on two threads, sorted by :func:`radix_sort` (three passes), and unpacked into the order, the
  sorted codes and each vertex's new number in one more;
- :func:`octree_cells`: the adaptive octree's leaves found depth first, a cell's children by binary
  searches in its groups' sorted codes (the numpy pass walks every group at every level);
- :func:`face_records`: a binary PLY's faces copied from the file's records (a count byte and three
  4-byte indices each), three bytes-to-index loads where numpy copies unaligned strided fields;
- :func:`face_pass`: each chunk's box and the smooth vertex normals in one pass: a face's normal is
  the cross product of two edges in float32 (twice its area), summed at its corners in float64 (as
  the numpy pass does), so a vertex's normal does not depend on the order of its faces. Two threads
  each take half the chunks and sum at their own vertices only (the second half's lowest vertex
  divides them), each vertex's faces still in order.

The functions are compiled on first use and kept by numba (``cache=True``: next to this file, or in
the user's cache folder when this one is read-only); a process loads them in tens of milliseconds.
Importing numba costs a node 0.4 s of CPU, so only the ingest (in the scene reader process) and
big meshes import it.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

#: Faces from which a mesh is split by the compiled passes.
COMPILED_FACES = 1 << 21

_kernels: Any = None


def available(face_total: int) -> bool:
    """Whether a mesh of ``face_total`` faces takes the compiled passes (big enough, numba installed)."""
    return face_total >= COMPILED_FACES and _compiled() is not None


def _compiled() -> Any:
    """The compiled kernels (a namespace), or None without numba."""
    global _kernels
    if _kernels is None:
        try:
            import numba
        except ImportError:
            _kernels = False
        else:
            try:
                _kernels = _build(numba.njit(cache=True, nogil=True))
            except RuntimeError:   # no folder to cache them in (a read-only install, no home): compiled each time
                _kernels = _build(numba.njit(nogil=True))
    return _kernels or None


def _build(jit: Any) -> Any:

    @jit
    def lowest_counts(faces: np.ndarray, first: int, end: int, rank: np.ndarray, lowest: np.ndarray,
                      counts: np.ndarray) -> None:
        last = np.uint32(rank.size - 1)
        for face in range(first, end):
            a = rank[min(faces[face, 0], last)]
            b = rank[min(faces[face, 1], last)]
            c = rank[min(faces[face, 2], last)]
            low = min(a, min(b, c))
            lowest[face] = low
            counts[low] += 1

    @jit
    def scatter(faces: np.ndarray, first: int, end: int, rank: np.ndarray, lowest: np.ndarray,
                next_slot: np.ndarray, new_faces: np.ndarray, face_order: np.ndarray) -> None:
        last = np.uint32(rank.size - 1)
        ordered = face_order.size > 0
        for face in range(first, end):
            low = lowest[face]
            slot = next_slot[low]
            next_slot[low] = slot + 1
            new_faces[slot, 0] = rank[min(faces[face, 0], last)]
            new_faces[slot, 1] = rank[min(faces[face, 1], last)]
            new_faces[slot, 2] = rank[min(faces[face, 2], last)]
            if ordered:
                face_order[slot] = face

    @jit
    def slot_starts(first_counts: np.ndarray, second_counts: np.ndarray, codes: np.ndarray, first_slot: np.ndarray,
                    second_slot: np.ndarray, groups: np.ndarray, group_codes: np.ndarray) -> int:
        """Each vertex's first slot for the first and the second half's faces, and the groups (first
        slot, vertex's code) of the vertices some face has as its lowest; returns how many groups."""
        total, group = 0, 0
        for vertex in range(first_counts.size):
            in_first, in_second = first_counts[vertex], second_counts[vertex]
            first_slot[vertex] = total
            second_slot[vertex] = total + in_first
            if in_first + in_second > 0:
                groups[group] = total
                group_codes[group] = codes[vertex]
                group += 1
            total += in_first + in_second
        return group

    @jit
    def sweep(positions: np.ndarray, faces: np.ndarray, starts: np.ndarray, first_chunk: int, end_chunk: int,
              vertex_lo: int, vertex_hi: int, boxes: np.ndarray, summed: np.ndarray, normals: bool) -> None:
        """Boxes of chunks [first_chunk, end_chunk) and, with ``normals``, the face normals summed at
        the corners in [vertex_lo, vertex_hi) of every face that has one there, in face order: the
        faces before the first chunk are scanned for such corners (faces sorted by their lowest
        vertex have none there once vertex_lo is at most the first chunk's lowest vertex)."""
        chunks, face_total = starts.size, faces.shape[0]
        last = np.uint32(positions.shape[0] - 1)
        lo_vertex, hi_vertex = np.uint32(vertex_lo), np.uint32(vertex_hi)

        def add_normal(ia: np.uint32, ib: np.uint32, ic: np.uint32) -> None:
            ax, ay, az = positions[ia, 0], positions[ia, 1], positions[ia, 2]
            ux, uy, uz = positions[ib, 0] - ax, positions[ib, 1] - ay, positions[ib, 2] - az
            vx, vy, vz = positions[ic, 0] - ax, positions[ic, 1] - ay, positions[ic, 2] - az
            nx = np.float64(uy * vz - uz * vy)
            ny = np.float64(uz * vx - ux * vz)
            nz = np.float64(ux * vy - uy * vx)
            for corner in (ia, ib, ic):
                if lo_vertex <= corner < hi_vertex:
                    summed[corner, 0] += nx
                    summed[corner, 1] += ny
                    summed[corner, 2] += nz

        if normals and 0 < first_chunk < chunks and vertex_lo < vertex_hi:
            for face in range(starts[first_chunk]):
                ia, ib, ic = min(faces[face, 0], last), min(faces[face, 1], last), min(faces[face, 2], last)
                if max(ia, max(ib, ic)) < lo_vertex or min(ia, min(ib, ic)) >= hi_vertex:
                    continue
                add_normal(ia, ib, ic)
        for chunk in range(first_chunk, end_chunk):
            end = starts[chunk + 1] if chunk + 1 < chunks else face_total
            lo0 = lo1 = lo2 = np.float32(np.inf)
            hi0 = hi1 = hi2 = np.float32(-np.inf)
            for face in range(starts[chunk], end):
                ia, ib, ic = min(faces[face, 0], last), min(faces[face, 1], last), min(faces[face, 2], last)
                ax, ay, az = positions[ia, 0], positions[ia, 1], positions[ia, 2]
                bx, by, bz = positions[ib, 0], positions[ib, 1], positions[ib, 2]
                cx, cy, cz = positions[ic, 0], positions[ic, 1], positions[ic, 2]
                lo0 = min(lo0, min(ax, min(bx, cx)))
                lo1 = min(lo1, min(ay, min(by, cy)))
                lo2 = min(lo2, min(az, min(bz, cz)))
                hi0 = max(hi0, max(ax, max(bx, cx)))
                hi1 = max(hi1, max(ay, max(by, cy)))
                hi2 = max(hi2, max(az, max(bz, cz)))
                if normals:
                    add_normal(ia, ib, ic)
            boxes[chunk, 0, 0], boxes[chunk, 0, 1], boxes[chunk, 0, 2] = lo0, lo1, lo2
            boxes[chunk, 1, 0], boxes[chunk, 1, 1], boxes[chunk, 1, 2] = hi0, hi1, hi2

    @jit
    def unit(summed: np.ndarray, first: int, end: int, out: np.ndarray) -> None:
        for vertex in range(first, end):
            x, y, z = summed[vertex, 0], summed[vertex, 1], summed[vertex, 2]
            length = np.sqrt(x * x + y * y + z * z)
            inverse = 1.0 / length if length > 0.0 else 0.0
            out[vertex, 0] = x * inverse
            out[vertex, 1] = y * inverse
            out[vertex, 2] = z * inverse

    @jit
    def radix_counts(keys: np.ndarray, first: int, end: int, shift: int, bits: int, counts: np.ndarray) -> None:
        """How many of keys [first, end) fall in each bucket of bits [shift, shift + bits), into ``counts``."""
        mask = np.uint64((1 << bits) - 1)
        shift64 = np.uint64(shift)
        for i in range(first, end):
            counts[(keys[i] >> shift64) & mask] += 1

    @jit
    def radix_scatter(keys: np.ndarray, first: int, end: int, shift: int, bits: int, slots: np.ndarray,
                      out: np.ndarray) -> None:
        """Keys [first, end) into ``out`` at their bucket's next slot (``slots``, advanced)."""
        mask = np.uint64((1 << bits) - 1)
        shift64 = np.uint64(shift)
        for i in range(first, end):
            key = keys[i]
            bucket = (key >> shift64) & mask
            out[slots[bucket]] = key
            slots[bucket] += 1

    @jit
    def face_records(data: np.ndarray, first: int, end: int, out: np.ndarray) -> tuple[bool, int]:
        """Faces [first, end) of a PLY's records of 13 bytes (a 1-byte count, three 4-byte little-endian
        indices) in ``data`` (uint8) into ``out`` (F, 3) uint32: (all counts 3, largest index)."""
        triangles, largest = True, np.uint32(0)
        for face in range(first, end):
            base = face * 13
            triangles = triangles and data[base] == 3
            for corner in range(3):
                at = base + 1 + 4 * corner
                value = (np.uint32(data[at]) | (np.uint32(data[at + 1]) << np.uint32(8))
                         | (np.uint32(data[at + 2]) << np.uint32(16)) | (np.uint32(data[at + 3]) << np.uint32(24)))
                out[face, corner] = value
                largest = max(largest, value)
        return triangles, int(largest)

    @jit
    def morton_keys(points: np.ndarray, first: int, end: int, lo: np.ndarray, scale: np.ndarray, top: float,
                    spread: np.ndarray, item_bits: int, keys: np.ndarray) -> int:
        """Keys (code << item_bits | number) of points [first, end) into ``keys``; the largest code.
        A coordinate's cell is clipped to [0, top] (NaN to 0), as numpy's clip and clipped take do."""
        largest = np.uint64(0)
        for point in range(first, end):
            code = np.uint64(0)
            for axis in range(3):
                cell = (np.float64(points[point, axis]) - lo[axis]) * scale[axis]
                index = 0 if not cell >= 0.0 else int(top) if cell > top else int(cell)
                code |= spread[index] << np.uint64(2 - axis)
            largest = max(largest, code)
            keys[point] = (code << np.uint64(item_bits)) | np.uint64(point)
        return int(largest)

    @jit
    def point_keys(world: np.ndarray, first: int, end: int, lo: np.ndarray, scale: float, top: float, flip: int,
                   index_bits: int, keys: np.ndarray) -> None:
        """Keys ((code ^ flip) << index_bits | number) of points [first, end) of ``world`` (N, 3)
        float64 into ``keys``: a coordinate's cell ``(w - lo) * scale`` clipped to [0, top] and
        floored, its 21 low bits spread three apart, axis a's at bit a (:func:`node.scene.points.build_octree`)."""
        for point in range(first, end):
            code = np.uint64(0)
            for axis in range(3):
                cell = (world[point, axis] - lo[axis]) * scale
                cell = min(max(cell, 0.0), top)
                x = np.uint64(np.uint32(cell)) & np.uint64(0x1FFFFF)
                x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
                x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
                x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
                x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
                x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
                code |= x << np.uint64(axis)
            keys[point] = ((code ^ np.uint64(flip)) << np.uint64(index_bits)) | np.uint64(point)

    @jit
    def unpack_keys(keys: np.ndarray, first: int, end: int, item_bits: int, order: np.ndarray,
                    rank: np.ndarray) -> None:
        mask = np.uint64((1 << item_bits) - 1)
        for slot in range(first, end):
            item = np.int64(keys[slot] & mask)
            order[slot] = item
            rank[item] = slot
            keys[slot] >>= np.uint64(item_bits)

    @jit
    def octree_cells(codes: np.ndarray, group_faces: np.ndarray, face_total: int, face_limit: int, max_depth: int,
                     starts: np.ndarray, ends: np.ndarray, depths: np.ndarray) -> int:
        """The leaves, depth first (so by first face), into ``starts``/``ends``/``depths`` when they
        have room (else only counted); returns how many."""
        groups = codes.size
        room = starts.size
        stack = np.empty((8 * (max_depth + 1) + 1, 3), np.int64)   # (first group, end group, depth)
        bounds = np.empty(9, np.int64)
        stack[0, 0], stack[0, 1], stack[0, 2] = 0, groups, 0
        top, count = 1, 0
        while top > 0:
            top -= 1
            g0, g1, depth = stack[top, 0], stack[top, 1], stack[top, 2]
            f0 = group_faces[g0]
            f1 = group_faces[g1] if g1 < groups else face_total
            if f1 - f0 <= face_limit or depth == max_depth:
                for first in range(f0, f1, face_limit if f1 - f0 > face_limit else max(f1 - f0, 1)):
                    if count < room:
                        starts[count], ends[count], depths[count] = first, min(first + face_limit, f1), depth
                    count += 1
                continue
            shift = np.uint64(3 * (max_depth - depth - 1))
            cell = codes[g0] >> (shift + np.uint64(3))
            bounds[0] = g0
            for child in range(8):
                below = ((cell << np.uint64(3)) + np.uint64(child + 1)) << shift   # the next child's first code
                low, high = bounds[child], g1
                while low < high:
                    middle = (low + high) >> 1
                    if codes[middle] < below:
                        low = middle + 1
                    else:
                        high = middle
                bounds[child + 1] = low
            for child in range(7, -1, -1):
                if bounds[child + 1] > bounds[child]:
                    stack[top, 0], stack[top, 1], stack[top, 2] = bounds[child], bounds[child + 1], depth + 1
                    top += 1
        return count

    class Kernels:
        pass

    kernels: Any = Kernels()
    kernels.lowest_counts, kernels.scatter, kernels.sweep, kernels.unit = lowest_counts, scatter, sweep, unit
    kernels.slot_starts = slot_starts
    kernels.radix_counts, kernels.radix_scatter, kernels.face_records = radix_counts, radix_scatter, face_records
    kernels.morton_keys, kernels.unpack_keys, kernels.octree_cells = morton_keys, unpack_keys, octree_cells
    kernels.point_keys = point_keys
    return kernels


def sorted_faces(faces: np.ndarray, rank: np.ndarray, codes: np.ndarray, face_order: bool = True) -> tuple[
        np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """``faces`` (F, 3) uint32 numbering old vertices, renumbered by ``rank`` (V,) uint32 (old vertex
    → new) and sorted by their lowest new vertex, then by number: (new faces (F, 3) uint32, face
    order (F,) int64: new face k is old face ``order[k]`` (None unless ``face_order``), the first new
    face of each group of one lowest vertex (G,) int64, and those vertices' ``codes`` (V,) uint64 (by
    new number) (G,) uint64). Indices past the last vertex are taken as the last (as
    ``take(mode="clip")``).

    A counting sort in two halves of the faces on two threads: each half counts its faces per lowest
    vertex, and the second half's faces of a vertex go after the first half's. Slots are 4-byte
    numbers where the faces allow (the scattering pass's random accesses touch half the memory)."""
    kernels = _compiled()
    faces = np.ascontiguousarray(faces, np.uint32)
    face_total, vertex_total = faces.shape[0], rank.size
    halves = [(0, face_total // 2), (face_total // 2, face_total)]
    lowest = np.empty(face_total, np.uint32)
    counts = [np.zeros(vertex_total, np.uint32) for _ in halves]
    _on_threads([lambda first=first, end=end, count=count: kernels.lowest_counts(faces, first, end, rank, lowest, count)
                 for (first, end), count in zip(halves, counts, strict=True)])
    slot_type = np.uint32 if face_total < 1 << 32 else np.int64
    first_slot, second_slot = np.empty(vertex_total, slot_type), np.empty(vertex_total, slot_type)
    groups, group_codes = np.empty(vertex_total, np.int64), np.empty(vertex_total, np.uint64)
    group_count = kernels.slot_starts(counts[0], counts[1], codes, first_slot, second_slot, groups, group_codes)
    del counts
    new_faces = np.empty((face_total, 3), np.uint32)
    order = np.empty(face_total if face_order else 0, np.int64)
    _on_threads([lambda first=first, end=end, slots=slots: kernels.scatter(faces, first, end, rank, lowest, slots,
                                                                             new_faces, order)
                 for (first, end), slots in zip(halves, (first_slot, second_slot), strict=True)])
    return new_faces, order if face_order else None, groups[:group_count], group_codes[:group_count]


def sorted_vertices(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, depth: int,
                    spread: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``points`` (N, 3) float32 sorted stably by their Morton codes at ``depth`` in the box [lo, hi]
    (3,) float64, as :func:`node.scene.octree.sorted_by_code` of :func:`node.scene.octree.morton_codes`
    sorts them (``spread`` (2**depth,) uint64: each cell index's bits three apart): (order (N,) int64,
    sorted codes (N,) uint64, rank (N,) uint32: point ``order[k]``'s new number is k); None when a code
    and a point's number do not fit one 64-bit key."""
    kernels = _compiled()
    points = np.ascontiguousarray(points, np.float32)
    count = len(points)
    item_bits = max(1, int(count - 1).bit_length())
    if 3 * depth + item_bits > 64:
        return None
    cells = 1 << depth
    scale = cells / np.maximum(np.asarray(hi, np.float64) - lo, np.finfo(np.float64).tiny)
    keys = np.empty(count, np.uint64)
    halves = [(0, count // 2), (count // 2, count)]
    largest: list[int] = []
    _on_threads([lambda first=first, end=end: largest.append(kernels.morton_keys(
        points, first, end, np.asarray(lo, np.float64), scale, float(cells - 1), spread, item_bits, keys))
        for first, end in halves])
    keys = radix_sort(keys, item_bits, max(max(largest).bit_length(), 1))
    order = np.empty(count, np.int64)
    rank = np.empty(count, np.uint32)
    _on_threads([lambda first=first, end=end: kernels.unpack_keys(keys, first, end, item_bits, order, rank)
                 for first, end in halves])
    return order, keys, rank


def sorted_point_keys(world: np.ndarray, lo: np.ndarray, scale: float, levels: int, flip: int,
                      index_bits: int) -> np.ndarray:
    """A point cloud's sort keys (N,) uint64, sorted: each point's Morton code over ``levels`` bits a
    side, ``flip`` XORed in, above its number (``index_bits``), as :func:`node.scene.points.build_octree`'s
    numpy pass makes and sorts them — codes made on two threads, then :func:`radix_sort`."""
    kernels = _compiled()
    world = np.ascontiguousarray(world, np.float64)
    count = len(world)
    keys = np.empty(count, np.uint64)
    lo = np.asarray(lo, np.float64)
    top = float((1 << levels) - 1)
    _on_threads([lambda first=first, end=end: kernels.point_keys(world, first, end, lo, scale, top, flip,
                                                                 index_bits, keys)
                 for first, end in ((0, count // 2), (count // 2, count))])
    return radix_sort(keys, index_bits, 3 * levels)


def octree_cells(codes: np.ndarray, group_faces: np.ndarray, face_total: int, face_limit: int,
                 max_depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`node.scene.octree._cells` compiled: (starts, ends, depths) (C,) int64 of the adaptive
    octree's leaves over groups of faces of one code (``codes`` (G,) uint64 sorted, group g's first
    face ``group_faces[g]`` (G,) int64), the same arrays, found depth first."""
    kernels = _compiled()
    codes = np.ascontiguousarray(codes, np.uint64)
    group_faces = np.ascontiguousarray(group_faces, np.int64)
    none = np.zeros(0, np.int64)
    count = kernels.octree_cells(codes, group_faces, face_total, face_limit, max_depth, none, none, none)
    starts, ends, depths = np.empty(count, np.int64), np.empty(count, np.int64), np.empty(count, np.int64)
    kernels.octree_cells(codes, group_faces, face_total, face_limit, max_depth, starts, ends, depths)
    return starts, ends, depths


def float16_bits(values: np.ndarray) -> np.ndarray:
    """``values`` (any shape) float32 as float16, rounded as numpy's ``astype(np.float16)`` rounds them
    (the same bits; numba has no float16): for tests and small arrays, :func:`interleave` packs."""
    from node.scene import compiled_packing  # numba's: imported where it is installed

    bits = np.ascontiguousarray(values, np.float32).view(np.uint32)
    out = np.empty(bits.shape, np.uint16)
    compiled_packing.halves(bits.reshape(-1), out.reshape(-1))
    return out.view(np.float16)


def interleave(positions: np.ndarray, normals: np.ndarray, rows: np.ndarray) -> None:
    """Vertices ``rows`` (N,) of a :class:`node.scene.packing.VertexLayout` dtype (position then
    normal first, its stride a whole number of 4-byte words) given their position and normal from
    ``positions`` and ``normals`` (N, 3) float32 (normals rounded to float16 as numpy rounds them,
    padding zero), in one compiled pass where numpy's field assignments take two and a conversion."""
    from node.scene import compiled_packing  # numba's: imported where it is installed

    if not len(positions) == len(normals) == len(rows) or rows.dtype.itemsize % 4:
        raise ValueError(f"{len(positions)} positions, {len(normals)} normals for {len(rows)} vertices of "
                         f"{rows.dtype.itemsize} bytes")
    words = rows.view(np.uint8).reshape(len(rows), rows.dtype.itemsize).view(np.uint32)
    compiled_packing.interleave(np.ascontiguousarray(positions, np.float32).view(np.uint32),
                       np.ascontiguousarray(normals, np.float32).view(np.uint32), words)


def face_records(records: np.ndarray) -> tuple[np.ndarray, bool, int]:
    """A binary PLY's face ``records`` (F,) of a 1-byte count and three 4-byte indices (13 bytes, as
    numpy maps them from the file), copied on two threads: (faces (F, 3) uint32, whether every count is
    3, the largest index; a negative one wraps to a large one, as numpy's copy does)."""
    kernels = _compiled()
    data = records.view(np.uint8)
    out = np.empty((records.size, 3), np.uint32)
    half = records.size // 2
    results: list[tuple[bool, int]] = []

    def copy(first: int, end: int) -> Callable[[], None]:
        return lambda: results.append(kernels.face_records(data, first, end, out))

    _on_threads([copy(0, half), copy(half, records.size)])
    return out, all(triangles for triangles, _ in results), max(largest for _, largest in results)


def _on_threads(works: list[Callable[[], None]]) -> None:
    """Each of ``works`` on a thread of its own (the compiled kernels release the GIL)."""
    with ThreadPoolExecutor(len(works)) as pool:
        for _ in pool.map(lambda work: work(), works):
            pass


def face_pass(positions: np.ndarray, faces: np.ndarray, starts: np.ndarray,
              normals: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """(boxes (C, 2, 3) float32, smooth unit normals (V, 3) float32 or None) of the chunks starting
    at faces ``starts`` (C,) of ``faces`` (F, 3) uint32 over ``positions`` (V, 3) float32, as
    :func:`node.scene.face_pass.face_pass` gives them (an index past the last vertex taken as the last)."""
    kernels = _compiled()
    positions = np.ascontiguousarray(positions, np.float32)
    faces = np.ascontiguousarray(faces, np.uint32)
    starts = np.ascontiguousarray(starts, np.int64)
    boxes = np.empty((starts.size, 2, 3), np.float32)
    vertex_total = len(positions)
    summed = np.zeros((vertex_total if normals else 0, 3), np.float64)
    # Two parts of the chunks, each part's thread summing the normals of its own vertices (those
    # below the second part's lowest vertex, and the rest), in face order: the same sums, bit for bit.
    middle = int(np.searchsorted(starts, faces.shape[0] // 2))
    parts = [(0, starts.size, 0, vertex_total)]
    if 0 < middle < starts.size and starts[middle] < faces.shape[0]:
        split = min(int(faces[starts[middle]:].min()), vertex_total - 1)
        parts = [(0, middle, 0, split), (middle, starts.size, split, vertex_total)]
    _on_threads([lambda part=part: kernels.sweep(positions, faces, starts, *part, boxes, summed, normals)
                 for part in parts])
    if not normals:
        return boxes, None
    unit = np.empty((vertex_total, 3), np.float32)
    half = vertex_total // 2
    _on_threads([lambda first=first, end=end: kernels.unit(summed, first, end, unit)
                 for first, end in ((0, half), (half, vertex_total))])
    return boxes, unit


def radix_sort(keys: np.ndarray, shift: int, bits: int) -> np.ndarray:
    """``keys`` (N,) uint64 sorted (stably) by their bits [shift, shift + bits), in passes of at most
    12 bits (4096 buckets, each pass's writes stay in cache), each pass on two threads (the second
    half's keys of a bucket after the first half's); the sorted array (``keys`` reused as scratch).
    Equal to ``numpy.sort`` when the bits below ``shift`` already ascend."""
    kernels = _compiled()
    passes = max(1, -(-bits // 12))
    step = -(-bits // passes)
    source, target = keys, np.empty_like(keys)
    halves = ((0, keys.size // 2), (keys.size // 2, keys.size))
    for first in range(shift, shift + bits, step):
        width = min(step, shift + bits - first)
        counts = np.zeros((2, 1 << width), np.int64)
        _on_threads([lambda part=part, count=count, source=source, first=first, width=width: kernels.radix_counts(
            source, *part, first, width, count) for part, count in zip(halves, counts, strict=True)])
        slots = np.cumsum(counts.T.reshape(-1)).reshape(-1, 2).T - counts   # bucket by bucket, first half first
        _on_threads([lambda part=part, slot=slot, source=source, target=target, first=first, width=width:
                     kernels.radix_scatter(source, *part, first, width, slot, target)
                     for part, slot in zip(halves, slots.copy(), strict=True)])
        source, target = target, source
    return source
