"""Big models for the big-model benchmarks: K×K copies of a real scan laid on a grid, written as one
binary PLY and one GLB of one mesh each.

``python -m bench.big_models --scan PATH --copies K [--out DIR] [--formats ply,glb]``

The copies sit side by side on the scan's two longest axes, 5 % of its size apart, in one mesh
(one vertex list, one face list), so a reader meets one big mesh as a user's scan would be. The
files are streamed copy by copy: the writer holds one copy's arrays at a time, never the model. The
scan's own vertices and faces are read with :func:`node.scene.ply.read_ply_arrays` (a binary PLY of
float xyz and uchar-counted int faces, as the shared scans are).
"""

from __future__ import annotations

import argparse
import json
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from node.scene.ply import read_ply_arrays

#: Gap between neighbouring copies, as a fraction of the scan's size along the axis.
GAP = 0.05


def grid_offsets(lo: np.ndarray, hi: np.ndarray, copies: int) -> np.ndarray:
    """(copies², 3) float32 translations of a ``copies`` × ``copies`` grid of a model whose box is
    [``lo``, ``hi``], laid on its two longest axes."""
    extent = np.asarray(hi, np.float64) - np.asarray(lo, np.float64)
    axes = np.argsort(extent)[::-1][:2]
    step = extent * (1.0 + GAP)
    rows, cols = np.divmod(np.arange(copies * copies), copies)
    offsets = np.zeros((copies * copies, 3))
    offsets[:, axes[0]] = cols * step[axes[0]]
    offsets[:, axes[1]] = rows * step[axes[1]]
    return offsets.astype(np.float32)


def _copies(vertices: np.ndarray, offsets: np.ndarray) -> Iterator[np.ndarray]:
    for offset in offsets:
        yield vertices + offset


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, offsets: np.ndarray) -> int:
    """Write the copies of (``vertices`` (V, 3) float32, ``faces`` (F, 3)) at ``offsets`` (K, 3) as one
    binary little-endian PLY at ``path``; returns the bytes written."""
    count = len(offsets)
    header = (f"ply\nformat binary_little_endian 1.0\ncomment Tessera bench.big_models: {count} copies\n"
              f"element vertex {count * len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {count * len(faces)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    record = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
    with path.open("wb") as out:
        out.write(header)
        for moved in _copies(vertices, offsets):
            out.write(moved.astype("<f4").tobytes())
        rows = np.empty(len(faces), record)
        rows["n"] = 3
        for copy in range(count):
            rows["v"] = faces + copy * len(vertices)
            out.write(rows.tobytes())
    return path.stat().st_size


def write_glb(path: Path, vertices: np.ndarray, faces: np.ndarray, offsets: np.ndarray) -> int:
    """Write the copies as one GLB of one mesh (POSITION float32, uint32 indices, no normals);
    returns the bytes written."""
    count = len(offsets)
    vertex_total, face_total = count * len(vertices), count * len(faces)
    position_bytes, index_bytes = vertex_total * 12, face_total * 12
    lo = (vertices.min(axis=0) + offsets.min(axis=0)).tolist()
    hi = (vertices.max(axis=0) + offsets.max(axis=0)).tolist()
    document = {
        "asset": {"version": "2.0", "generator": "Tessera bench.big_models"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": path.stem}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": position_bytes + index_bytes}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": position_bytes, "target": 34962},
                        {"buffer": 0, "byteOffset": position_bytes, "byteLength": index_bytes, "target": 34963}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": vertex_total, "type": "VEC3",
                       "min": lo, "max": hi},
                      {"bufferView": 1, "componentType": 5125, "count": face_total * 3, "type": "SCALAR"}],
    }
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = position_bytes + index_bytes
    with path.open("wb") as out:
        out.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + binary))
        out.write(struct.pack("<I4s", len(text), b"JSON") + text)
        out.write(struct.pack("<I4s", binary, b"BIN\x00"))
        for moved in _copies(vertices, offsets):
            out.write(moved.astype("<f4").tobytes())
        for copy in range(count):
            out.write((faces + copy * len(vertices)).astype("<u4").tobytes())
    return path.stat().st_size


def make_models(scan: Path, copies: int, out: Path, formats: tuple[str, ...] = ("ply", "glb")) -> list[Path]:
    """Write ``scan`` laid ``copies`` × ``copies`` as each of ``formats`` into ``out``; returns the paths
    (a file already there with the same name is kept: delete it to write it again)."""
    vertices, faces = read_ply_arrays(scan)
    offsets = grid_offsets(vertices.min(axis=0), vertices.max(axis=0), copies)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for suffix in formats:
        path = out / f"{scan.stem}_{copies}x{copies}.{suffix}"
        if not path.exists():
            partial = path.with_name(f".{path.name}.part")
            (write_ply if suffix == "ply" else write_glb)(partial, vertices, faces, offsets)
            partial.replace(path)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.big_models", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scan", type=Path, required=True, help="a binary PLY scan (float xyz, int faces)")
    parser.add_argument("--copies", type=int, required=True, help="K: the model holds K x K copies")
    parser.add_argument("--out", type=Path, default=Path("/tmp/tessera-big-models"), help="folder to write into")
    parser.add_argument("--formats", default="ply,glb", help="comma-separated: ply, glb")
    args = parser.parse_args(argv)
    for path in make_models(args.scan, args.copies, args.out, tuple(args.formats.split(","))):
        print(f"{path} ({path.stat().st_size / 1e6:.0f} MB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
