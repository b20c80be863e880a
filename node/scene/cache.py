"""The scene cache's entries (issue 31: ingest once, open in seconds): a scene read, split into
chunks and packed, stored as the GPU takes it, and opened again by mapping its files. No GL here;
the folder the entries live in (naming by content, locks, eviction) is :mod:`node.scene.cache_folder`.

An entry is a directory holding ``table.json`` (the format version, the source's SHA-256 and size,
the batches' materials, the objects, animations, bounds) and one ``.npy`` file per array:
``vertices`` (V,) of the :class:`node.scene.packing.VertexLayout`, ``indices`` (3F,) uint32 batch-local,
``vertex_bounds`` (B + 1,), the chunk table (``chunk_batch`` (C,), ``index_bounds`` (C + 1,),
``batch_bounds`` (B + 1,), ``chunk_boxes`` (C, 2, 3)), the culling tree over the chunk boxes
(``bvh-*``, :func:`node.culling.bvh.bvh_arrays`: opening an entry builds no tree, 0.4–0.7 s at 441k
chunks), ``extras`` (V, 6) float32 (tangents and second uvs, when some batch has them) and
``texture-N`` (h, w, 4) uint8. Each array's bytes carry a CRC-32 per :data:`BLOCK_BYTES` block in
the table.

Written into a temporary directory and renamed into place whole, ``table.json`` last: an entry
either is complete or is not there, whatever kills the writer. Opened with ``numpy.load(mmap_mode='r')``:
nothing is read until used, and the pages of processes on one host are the OS page cache's, shared.
An entry of another format version, or whose table does not parse, whose files are missing, of
other shapes, or whose bytes fail their CRC, raises :class:`CacheError` (the folder then builds it
again), so it is never drawn.

A sort-last share (:func:`write_share`) is an entry of its own: the chunks of the share, the vertices
they use and their indices renumbered, read from the whole scene's entry by the byte ranges of those
chunks only, so a node's memory follows its share.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import zlib
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from node.culling.bvh import build_chunk_bvh, bvh_arrays, bvh_from_arrays
from node.scene.chunks import SceneChunks
from node.scene.data import SceneData
from node.scene.material import SurfaceMaterial, UvTransform
from node.scene.mesh import MeshBatch
from node.scene.packing import PackedGeometry, VertexLayout, vertex_extras
from node.scene.pages import release_pages
from tessera.decomposition.data_partition import split_chunks
from tessera.scene.animation import Animation
from tessera.scene.graph import ObjectGraph

#: The entry format: an entry of another is built again, never read (2: the culling tree kept).
CACHE_FORMAT = 2
#: The prefix of the culling tree's arrays in an entry.
TREE_PREFIX = "bvh-"
#: Bytes a CRC-32 covers.
BLOCK_BYTES = 16 << 20
TABLE = "table.json"
#: Arrays an entry's writer writes (and checksums) at once.
WRITERS = 2
#: ``progress(fraction 0…1, message)``.
Progress = Callable[[float, str], None]


class CacheError(Exception):
    """An entry that cannot be used (absent, of another version, torn or corrupt); the message says why."""


@dataclass(frozen=True, slots=True)
class EntryInfo:
    """What an entry's table says of it: ``bytes`` on disk, ``triangles``, ``vertex_bytes`` and
    ``index_bytes`` (what the GPU holds of it)."""

    bytes: int
    triangles: int
    vertex_bytes: int
    index_bytes: int

    @property
    def gpu_bytes(self) -> int:
        return self.vertex_bytes + self.index_bytes


def _crcs(array: np.ndarray) -> list[int]:
    """CRC-32 of each :data:`BLOCK_BYTES` block of ``array``'s bytes (C order), pages handed back as read."""
    return [block_crc(array, block) for block in range(max(-(-array.nbytes // BLOCK_BYTES), 1))]


def block_crc(array: np.ndarray, block: int) -> int:
    """CRC-32 of block ``block`` (:data:`BLOCK_BYTES` each) of ``array``'s bytes (C order), its pages
    handed back as read."""
    flat = array.reshape(-1).view(np.uint8) if array.size else np.zeros(0, np.uint8)
    first = block * BLOCK_BYTES
    crc = zlib.crc32(flat[first:first + BLOCK_BYTES])
    release_pages(flat, first, min(first + BLOCK_BYTES, flat.size))
    return crc


def _material_json(material: SurfaceMaterial, texture_id: Callable[[np.ndarray | None], int | None]) -> dict[str, Any]:
    return {"metallic": material.metallic, "roughness": material.roughness, "emissive": list(material.emissive),
            "normal_scale": material.normal_scale, "occlusion_strength": material.occlusion_strength,
            "uv_transforms": [[list(t.matrix), t.uv_set] for t in material.uv_transforms],
            "textures": [texture_id(texture) for texture in material.textures()]}


def _material(data: Mapping[str, Any], textures: Sequence[np.ndarray]) -> SurfaceMaterial:
    maps = [None if number is None else textures[number] for number in data["textures"]]
    emissive = tuple(float(v) for v in data["emissive"])
    return SurfaceMaterial(
        metallic=float(data["metallic"]), roughness=float(data["roughness"]),
        emissive=(emissive[0], emissive[1], emissive[2]), normal_scale=float(data["normal_scale"]),
        occlusion_strength=float(data["occlusion_strength"]), metallic_roughness_texture=maps[0],
        normal_texture=maps[1], occlusion_texture=maps[2], emissive_texture=maps[3],
        uv_transforms=tuple(UvTransform((m[0], m[1], m[2], m[3], m[4], m[5]), int(uv_set))
                            for m, uv_set in data["uv_transforms"]))


def write_arrays(directory: Path, arrays: Mapping[str, np.ndarray], table: Mapping[str, Any]) -> int:
    """Write ``arrays`` (one ``.npy`` each, with their CRCs) and ``table`` (plus ``files`` and
    ``bytes``) as the entry ``directory``, atomically: into a temporary directory renamed into place
    whole, the table last. Returns the bytes written; an entry already there is kept (whoever wrote
    it first wins)."""
    temporary = directory.with_name(f".{directory.name}.{os.getpid()}.{os.urandom(4).hex()}.tmp")
    temporary.mkdir(parents=True)

    def write(name: str, array: np.ndarray) -> dict[str, Any]:
        np.save(temporary / f"{name}.npy", array, allow_pickle=False)
        return {"dtype": array.dtype.descr if array.dtype.names else array.dtype.str,
                "shape": list(array.shape), "crc32": _crcs(array)}

    try:
        # Two at a time: the writes' copies into the page cache and zlib's CRCs release the GIL.
        with ThreadPoolExecutor(WRITERS) as pool:
            files = dict(zip(arrays, pool.map(write, arrays, arrays.values()), strict=True))
        size = sum(path.stat().st_size for path in temporary.iterdir())
        (temporary / TABLE).write_text(json.dumps({**table, "files": files, "bytes": size}))
        try:
            os.rename(temporary, directory)
        except OSError:
            if not (directory / TABLE).is_file():
                raise
        return size
    finally:
        if temporary.exists():
            shutil.rmtree(temporary, ignore_errors=True)


def read_arrays(directory: Path, verify: bool = True, format_version: int = CACHE_FORMAT) -> tuple[
        dict[str, Any], dict[str, np.ndarray]]:
    """(table, arrays mapped) of the entry ``directory`` written by :func:`write_arrays`; ``verify``:
    check every array's CRCs (reading it all). Raises CacheError."""
    table = read_table(directory, format_version)
    try:
        return table, {key: _load_array(directory, key, spec, verify) for key, spec in table["files"].items()}
    except (KeyError, TypeError, ValueError) as exc:
        raise CacheError(f"{directory.name}: inconsistent table ({type(exc).__name__}: {exc})") from None


def write_entry(directory: Path, scene: SceneData, packed: PackedGeometry, source: Mapping[str, Any],
                share: Mapping[str, Any] | None = None) -> int:
    """Write ``scene`` (its batches packed as ``packed``) as the entry ``directory`` (:func:`write_arrays`);
    ``source`` (sha256, bytes, name) and ``share`` (index, weights) go into its table."""
    textures: list[np.ndarray] = []
    ids: dict[int, int] = {}

    def texture_id(texture: np.ndarray | None) -> int | None:
        if texture is None:
            return None
        if id(texture) not in ids:
            ids[id(texture)] = len(textures)
            textures.append(np.ascontiguousarray(texture, np.uint8))
        return ids[id(texture)]

    batches = [{"name": b.name, "owner": b.owner, "base_color": [float(v) for v in b.base_color],
                "alpha_mode": b.alpha_mode, "alpha_cutoff": b.alpha_cutoff,
                "texture": texture_id(b.texture), "material": _material_json(b.material, texture_id),
                "uvs": b.uvs is not None, "colors": b.colors is not None,
                "tangents": b.tangents is not None, "uvs1": b.uvs1 is not None} for b in scene.batches]
    chunks = scene.chunks
    arrays: dict[str, np.ndarray] = {
        "vertices": packed.vertices, "indices": packed.indices, "vertex_bounds": packed.vertex_bounds,
        "chunk_batch": chunks.batch, "index_bounds": chunks.index_bounds, "batch_bounds": chunks.batch_bounds,
        "chunk_boxes": chunks.boxes}
    tree = build_chunk_bvh(chunks.boxes) if chunks.tree is None else chunks.tree
    arrays.update({TREE_PREFIX + name: array for name, array in bvh_arrays(tree).items()})
    extras = vertex_extras(scene.batches)
    if extras is not None:
        arrays["extras"] = extras
    arrays.update({f"texture-{number}": texture for number, texture in enumerate(textures)})
    table = {"format": CACHE_FORMAT, "source": dict(source), "share": None if share is None else dict(share),
             "face_limit": chunks.face_limit, "layout": packed.layout.to_json(), "bounds": scene.bounds.tolist(),
             "triangles": scene.triangle_count, "batches": batches, "objects": scene.objects.to_json(),
             "animations": [a.keyframes_json() for a in scene.animations],
             "vertex_bytes": int(packed.vertices.nbytes), "index_bytes": int(packed.indices.nbytes)}
    return write_arrays(directory, arrays, table)


def read_table(directory: Path, format_version: int = CACHE_FORMAT) -> dict[str, Any]:
    """The entry's table; raises CacheError when absent, unparsable or of another format than
    ``format_version``."""
    try:
        table = json.loads((directory / TABLE).read_text())
    except FileNotFoundError:
        raise CacheError(f"{directory.name}: no entry") from None
    except (OSError, ValueError) as exc:
        raise CacheError(f"{directory.name}: unreadable table ({exc})") from None
    if not isinstance(table, dict) or table.get("format") != format_version:
        found = table.get("format") if isinstance(table, dict) else None
        raise CacheError(f"{directory.name}: format {found!r}, this node reads format {format_version}")
    return table


def entry_info(directory: Path) -> EntryInfo:
    """The sizes an entry's table gives (of any format: the folder weighs and evicts them all);
    raises CacheError."""
    try:
        table = json.loads((directory / TABLE).read_text())
        return EntryInfo(int(table["bytes"]), int(table.get("triangles", 0)), int(table.get("vertex_bytes", 0)),
                         int(table.get("index_bytes", 0)))
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise CacheError(f"{directory.name}: unreadable table ({exc})") from None


def _load_array(directory: Path, name: str, spec: Mapping[str, Any], verify: bool) -> np.ndarray:
    path = directory / f"{name}.npy"
    try:
        array = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise CacheError(f"{directory.name}: {name}.npy unreadable ({' '.join(str(exc).split())})") from None
    dtype = np.dtype([tuple(field) for field in spec["dtype"]]) if isinstance(spec["dtype"], list) else \
        np.dtype(spec["dtype"])
    if array.dtype != dtype or list(array.shape) != list(spec["shape"]):
        raise CacheError(f"{directory.name}: {name}.npy holds {array.dtype} {array.shape}, the table says "
                         f"{dtype} {tuple(spec['shape'])}")
    if verify and _crcs(array) != list(spec["crc32"]):
        raise CacheError(f"{directory.name}: {name}.npy fails its checksum (corrupt)")
    return array


def open_entry(directory: Path, name: str, verify: bool = True) -> SceneData:
    """The scene of the entry ``directory``, named ``name``, its geometry mapped (:attr:`SceneData.geometry`;
    the batches' arrays are views of it); ``verify``: check every array's CRCs first (reading it
    all). Raises CacheError."""
    table, arrays = read_arrays(directory, verify)
    try:
        return _scene(table, arrays, name)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise CacheError(f"{directory.name}: inconsistent table ({type(exc).__name__}: {exc})") from None


def _scene(table: Mapping[str, Any], arrays: Mapping[str, np.ndarray], name: str) -> SceneData:
    layout = VertexLayout(bool(table["layout"]["uvs"]), bool(table["layout"]["colors"]))
    vertices, indices = arrays["vertices"], arrays["indices"]
    vertex_bounds = np.array(arrays["vertex_bounds"], np.int64)
    chunks = SceneChunks(np.array(arrays["chunk_batch"], np.int64), np.array(arrays["index_bounds"], np.int64),
                         np.array(arrays["batch_bounds"], np.int64), np.array(arrays["chunk_boxes"], np.float32),
                         int(table["face_limit"]),
                         bvh_from_arrays({name[len(TREE_PREFIX):]: array for name, array in arrays.items()
                                          if name.startswith(TREE_PREFIX)}))
    if chunks.tree is None or chunks.tree.chunk_count != chunks.chunk_count:
        raise ValueError(f"a culling tree over {chunks.chunk_count} chunks expected")
    batch_index_bounds = chunks.index_bounds[chunks.batch_bounds]
    textures = [np.array(arrays[f"texture-{n}"]) for n in range(sum(k.startswith("texture-") for k in arrays))]
    extras = arrays.get("extras")
    batches = []
    for number, data in enumerate(table["batches"]):
        v0, v1 = int(vertex_bounds[number]), int(vertex_bounds[number + 1])
        i0, i1 = int(batch_index_bounds[number]), int(batch_index_bounds[number + 1])
        rows = vertices[v0:v1]
        batches.append(MeshBatch(
            name=str(data["name"]), positions=rows["position"], normals=rows["normal"],
            faces=indices[i0:i1].reshape(-1, 3), uvs=rows["uv"] if data["uvs"] else None,
            colors=rows["color"] if data["colors"] else None,
            base_color=np.asarray(data["base_color"], np.float32),
            texture=None if data["texture"] is None else textures[data["texture"]],
            alpha_mode=str(data["alpha_mode"]), alpha_cutoff=float(data["alpha_cutoff"]), owner=int(data["owner"]),
            material=_material(data["material"], textures),
            tangents=extras[v0:v1, :4] if extras is not None and data["tangents"] else None,
            uvs1=extras[v0:v1, 4:] if extras is not None and data["uvs1"] else None))
    objects = ObjectGraph.from_json(table["objects"])
    owners = np.array([b.owner for b in batches], np.int64)
    return SceneData(name, tuple(batches), np.asarray(table["bounds"], np.float64), int(table["triangles"]),
                     chunks.primitive_groups(owners), chunks, objects,
                     tuple(Animation.from_keyframes_json(a) for a in table["animations"]),
                     PackedGeometry(layout, vertices, indices, vertex_bounds))


def share_chunks(scene: SceneData, weights: Sequence[float], index: int) -> np.ndarray:
    """(C,) bool: the chunks of share ``index`` of ``scene`` split over ``weights`` (one per share)."""
    chunks = scene.chunks
    return split_chunks(chunks.boxes, chunks.face_counts, weights) == index


def write_share(directory: Path, whole: SceneData, weights: Sequence[float], index: int,
                source: Mapping[str, Any]) -> int:
    """Write share ``index`` of ``whole`` (an opened entry) split over ``weights`` as the entry
    ``directory``: its chunks (in their order), the vertices they use (in their order) and their
    indices renumbered, with the whole scene's bounds and objects. Reads only those chunks' index
    ranges and the pages of the vertices they use. Raises CacheError when the share holds no chunk."""
    assert whole.geometry is not None, "a share is read from an opened entry"
    geometry, chunks = whole.geometry, whole.chunks
    keep = share_chunks(whole, weights, index)
    if not keep.any():
        raise CacheError(f"share {index} of {len(weights)} holds no chunk")
    batches, vertex_parts, chunk_batch, chunk_faces, boxes = [], [], [], [], []
    for number, batch in enumerate(whole.batches):
        first, end = int(chunks.batch_bounds[number]), int(chunks.batch_bounds[number + 1])
        kept = np.flatnonzero(keep[first:end]) + first
        if kept.size == 0:
            continue
        local = _ranges(geometry.indices, chunks.index_bounds[kept], chunks.index_bounds[kept + 1])
        used = np.zeros(batch.vertex_count, bool)
        used[local] = True
        renumber = np.cumsum(used, dtype=np.uint32) - np.uint32(1)
        v0 = int(geometry.vertex_bounds[number])
        rows = geometry.vertices[v0:v0 + batch.vertex_count][used]
        vertex_parts.append(rows)
        batches.append(dataclasses.replace(
            batch, positions=rows["position"], normals=rows["normal"], faces=renumber[local].reshape(-1, 3),
            uvs=rows["uv"] if batch.uvs is not None else None,
            colors=rows["color"] if batch.colors is not None else None,
            tangents=None if batch.tangents is None else np.asarray(batch.tangents)[used],
            uvs1=None if batch.uvs1 is None else np.asarray(batch.uvs1)[used]))
        chunk_batch.append(np.full(kept.size, len(batches) - 1, np.int64))
        chunk_faces.append(chunks.face_counts[kept])
        boxes.append(chunks.boxes[kept])
    faces = np.concatenate(chunk_faces)
    table = SceneChunks(np.concatenate(chunk_batch), np.concatenate(([0], np.cumsum(faces * 3))),
                        np.concatenate(([0], np.cumsum([len(c) for c in chunk_batch]))), np.concatenate(boxes),
                        chunks.face_limit)
    vertex_counts = np.array([b.vertex_count for b in batches], np.int64)
    packed = PackedGeometry(geometry.layout, np.concatenate(vertex_parts),
                            np.concatenate([b.faces.reshape(-1) for b in batches]),
                            np.concatenate(([0], np.cumsum(vertex_counts))))
    share = SceneData(whole.name, tuple(batches), whole.bounds, int(faces.sum()), whole.groups, table, whole.objects,
                      whole.animations)
    return write_entry(directory, share, packed, source, {"index": index, "weights": list(weights)})


def _ranges(values: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """``values[starts[i]:ends[i]]`` for all i, concatenated (uint32 copy): touching ranges are read as one."""
    joined = np.flatnonzero(np.concatenate(([True], starts[1:] != ends[:-1])))
    run_ends = np.append(joined[1:], starts.size) - 1
    return np.concatenate([values[int(starts[a]):int(ends[b])] for a, b in zip(joined, run_ends, strict=True)]) \
        .astype(np.uint32)


def remove_entry(directory: Path) -> None:
    """Delete an entry (its files vanish from the folder; processes that mapped them keep their pages)."""
    if not directory.exists():
        return
    trash = directory.with_name(f".{directory.name}.{os.getpid()}.{os.urandom(4).hex()}.gone")
    with contextlib.suppress(OSError):
        os.rename(directory, trash)
        shutil.rmtree(trash, ignore_errors=True)
