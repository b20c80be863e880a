"""Scene loading for retained-mode rendering (seed 002): every node loads the whole scene once.

Loads glTF/GLB (with external .bin/.png), OBJ, PLY and STL through trimesh, or a generated
``builtin:NAME`` scene (:mod:`node.scene.builtin`), into world-space mesh batches ready for upload.
No GL and no culling here.

glTF node transforms and instancing are baked: each (node, mesh) pair of the scene graph becomes
one :class:`MeshBatch` with world-space positions and normals (normals by the inverse-transpose).
Scans without normals get smooth, area-weighted vertex normals. Colours are linear RGBA in 0…1;
textures stay sRGB-encoded bytes (the renderer samples them as sRGB).

Batches over the face limit are pre-split into octree chunks as they are gathered into a
:class:`SceneData` (seed 002 §3.4, :mod:`node.scene.chunks`).

Objects (issue 11): a glTF file's nodes, each batch owned by the node that carries its mesh, and
the file's animations (:mod:`node.scene.objects`); a PLY, OBJ or STL file is one object, named
after the file without its suffix.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from node.scene.builtin import build_builtin_scene
from node.scene.data import SceneData
from node.scene.gltf_vertices import VertexExtras, position_key, vertex_extras
from node.scene.material import DEFAULT_METALLIC, DEFAULT_ROUGHNESS, MaterialExtras, SurfaceMaterial, material_extras
from node.scene.mesh import DEFAULT_BASE_COLOR, MeshBatch, SceneError
from node.scene.normals import normalized, smooth_vertex_normals
from node.scene.objects import GLTF_SUFFIXES, file_animations, geometry_owners, gltf_objects, read_gltf
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.scene.ply import read_ply
from node.scene.point_files import is_point_file
from tessera.scene.animation import Animation
from tessera.scene.graph import SceneObject

BUILTIN_PREFIX = "builtin:"
#: Every scene file suffix: meshes, and point clouds (issue 36: LAS, LAZ, and PLY files without faces,
#: read by :mod:`node.scene.point_cache`).
SUPPORTED_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".las", ".laz")

#: ``progress(fraction 0…1, message)``: called while a scene loads.
ProgressCallback = Callable[[float, str], None]


def load_scene(spec: str, progress: ProgressCallback | None = None,
               face_limit: int = DEFAULT_FACE_LIMIT) -> SceneData:
    """Load ``spec`` (a file path or ``builtin:NAME``), split into chunks of at most ``face_limit``
    faces; raises SceneError with a one-line reason."""
    report = progress or (lambda fraction, message: None)
    if face_limit < 1:
        raise SceneError(f"{spec}: face limit must be ≥ 1, got {face_limit}")
    if spec.startswith(BUILTIN_PREFIX):
        report(0.0, f"generating {spec}")
        return build_builtin_scene(spec[len(BUILTIN_PREFIX):]).with_face_limit(face_limit)
    path = Path(spec)
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise SceneError(f"{spec}: unsupported file type {suffix or '(none)'!r}; "
                         f"supported: {', '.join(SUPPORTED_SUFFIXES)}")
    if not path.is_file():
        raise SceneError(f"{spec}: no such file")
    if is_point_file(path):
        raise SceneError(f"{spec}: a point cloud, not a mesh (node.scene.point_cache reads it)")
    report(0.0, f"reading {path.name}")
    started = time.perf_counter()
    if suffix == ".ply":
        batch = _ply_batch(path)
        report(0.3, f"read {path.name} in {time.perf_counter() - started:.1f} s: {batch.triangle_count} triangles; "
                    "splitting into chunks")
        return SceneData.from_batches(spec, [batch], face_limit, [SceneObject(path.stem)])
    try:
        import trimesh

        loaded = trimesh.load(str(path), force="scene", process=False)
    except FileNotFoundError as exc:
        raise SceneError(f"{spec}: a file it refers to is missing ({_one_line(exc)})") from None
    except Exception as exc:  # trimesh and its parsers raise many types for corrupt input
        raise SceneError(f"{spec}: corrupt or unreadable {suffix[1:].upper()} ({_one_line(exc)})") from None
    report(0.5, f"read {path.name} in {time.perf_counter() - started:.1f} s; baking instances, splitting")
    try:
        objects, owners, animations, extras_by_name, vertices_by_key = _file_objects(path, loaded)
        batches = batches_from_trimesh(loaded, owners, extras_by_name, vertices_by_key)
    except SceneError as exc:
        raise SceneError(f"{spec}: {exc}") from None
    except Exception as exc:
        raise SceneError(f"{spec}: corrupt geometry ({_one_line(exc)})") from None
    return SceneData.from_batches(spec, batches, face_limit, objects, animations)


def _ply_batch(path: Path) -> MeshBatch:
    """The one batch of the PLY file at ``path`` (:mod:`node.scene.ply`): its normals when it has
    them (else computed once split), its colours when it has them (sRGB bytes made linear)."""
    mesh = read_ply(path)
    if len(mesh.faces) == 0:
        raise SceneError(f"{path}: no triangles")
    faces = _drop_nonfinite_faces(mesh.vertices, mesh.faces)
    normals = None if mesh.normals is None else normalized(mesh.normals)
    colors = None if mesh.colors is None else _linear_rgba(mesh.colors)
    return MeshBatch(name=path.stem, positions=mesh.vertices, normals=normals, faces=faces, colors=colors)


def _file_objects(path: Path, scene: Any) -> tuple[list[SceneObject], dict[str, int] | None, tuple[Animation, ...],
                                                  dict[str, MaterialExtras], dict[bytes, VertexExtras]]:
    """The objects of the file at ``path`` (loaded as the trimesh ``scene``), each geometry node's
    owner among them (None: all the first's), the file's animations and what trimesh drops of its
    materials, by name, and of its vertices, by :func:`node.scene.gltf_vertices.position_key`."""
    if path.suffix.lower() in GLTF_SUFFIXES:
        document = read_gltf(path)
        objects, index = gltf_objects(document.json)
        extras_by_name = material_extras(document.json)
        vertices_by_key = vertex_extras(document)
        if objects:
            owners = geometry_owners(scene.graph, objects)
            return objects, owners, file_animations(document, index, objects), extras_by_name, vertices_by_key
        return [SceneObject(path.stem)], None, (), extras_by_name, vertices_by_key
    return [SceneObject(path.stem)], None, (), {}, {}


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


def batches_from_trimesh(scene: Any, owners: Mapping[str, int] | None = None,
                         extras_by_name: Mapping[str, MaterialExtras] | None = None,
                         vertices_by_key: Mapping[bytes, VertexExtras] | None = None) -> list[MeshBatch]:
    """World-space batches of a ``trimesh.Scene``: one per (graph node, triangle mesh), owned by
    object ``owners[graph node]`` (None: object 0); ``extras_by_name``: :class:`MaterialExtras` by
    material name; ``vertices_by_key``: tangents and second uvs by the meshes' positions."""
    import trimesh

    textures: dict[int, np.ndarray] = {}
    batches = []
    for node_name in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node_name]
        mesh = scene.geometry[geometry_name]
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue
        owner = 0 if owners is None else owners[node_name]
        batches.append(_batch_from_mesh(f"{node_name}/{geometry_name}", mesh, transform, textures, owner,
                                        extras_by_name or {}, vertices_by_key or {}))
    return batches


def _batch_from_mesh(name: str, mesh: Any, transform: np.ndarray, textures: dict[int, np.ndarray],
                     owner: int, extras_by_name: Mapping[str, MaterialExtras],
                     vertices_by_key: Mapping[bytes, VertexExtras]) -> MeshBatch:
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if len(vertices) == 0 or faces.min() < 0 or faces.max() >= len(vertices):
        raise SceneError("face indices out of range")
    # Normals the file provides are in trimesh's cache (looked up without its check, which hashes
    # every array); otherwise they are computed once the mesh is split.
    given_normals = "vertex_normals" in mesh._cache.cache
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64) if given_normals else None
    uvs = colors = texture = tangents = uvs1 = None
    base_color = np.asarray(DEFAULT_BASE_COLOR, dtype=np.float32)
    alpha_mode, alpha_cutoff = "OPAQUE", 0.5
    surface = SurfaceMaterial()
    visual = mesh.visual
    if visual.kind == "texture" and getattr(visual, "material", None) is not None:
        material = visual.material
        converted = not hasattr(material, "baseColorFactor")
        if converted and hasattr(material, "to_pbr"):
            material = material.to_pbr()
        factor = getattr(material, "baseColorFactor", None)
        base_color = np.ones(4, np.float32) if factor is None else np.asarray(factor, np.float32) / 255.0
        has_uvs = visual.uv is not None and len(visual.uv) == len(vertices)
        surface = _surface_material(material, converted, has_uvs, textures, extras_by_name)
        image = getattr(material, "baseColorTexture", None)
        if has_uvs and (image is not None or surface.textured):
            uvs = np.asarray(visual.uv, dtype=np.float32)
        if image is not None and has_uvs:
            texture = _texture_array(image, textures)
        if uvs is not None and vertices_by_key:
            tangents, uvs1 = _vertex_extras(surface, vertices_by_key.get(position_key(vertices)), transform)
        alpha_mode = str(getattr(material, "alphaMode", None) or "OPAQUE").upper()
        cutoff = getattr(material, "alphaCutoff", None)
        alpha_cutoff = 0.5 if cutoff is None else float(cutoff)
        attribute_colors = visual.vertex_attributes.get("color")
        if attribute_colors is not None and len(attribute_colors) == len(vertices):
            colors = _linear_rgba(np.asarray(attribute_colors))
    elif visual.kind == "vertex":
        colors = _linear_rgba(np.asarray(visual.vertex_colors))
    elif visual.kind == "face":
        face_colors = _linear_rgba(np.asarray(visual.face_colors))
        if normals is None:
            normals = smooth_vertex_normals(vertices, faces)
        vertices, normals = vertices[faces].reshape(-1, 3), normals[faces].reshape(-1, 3)
        colors = np.repeat(face_colors, 3, axis=0)
        faces = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
    identity = np.array_equal(transform, np.identity(4))
    world = vertices if identity else vertices @ transform[:3, :3].T + transform[:3, 3]
    faces = _drop_nonfinite_faces(world, faces)
    world_normals = None if normals is None else normalized(normals if identity else
                                                            normals @ np.linalg.inv(transform[:3, :3]))
    return MeshBatch(
        name=name,
        positions=world.astype(np.float32),
        normals=None if world_normals is None else world_normals.astype(np.float32),
        faces=faces.astype(np.uint32),
        uvs=uvs,
        colors=colors,
        base_color=base_color,
        texture=texture,
        alpha_mode=alpha_mode if alpha_mode in ("OPAQUE", "MASK", "BLEND") else "OPAQUE",
        alpha_cutoff=alpha_cutoff,
        owner=owner,
        material=surface,
        tangents=tangents,
        uvs1=uvs1,
    )


def _vertex_extras(surface: SurfaceMaterial, extras: VertexExtras | None,
                   transform: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The tangents (in world space: xyz by the node's linear part, w negated where it mirrors) and
    second uvs of a textured mesh, each kept only when its material uses them."""
    if extras is None:
        return None, None
    tangents = None
    if extras.tangents is not None and surface.normal_texture is not None:
        linear = transform[:3, :3]
        xyz = normalized(extras.tangents[:, :3].astype(np.float64) @ linear.T)
        w = np.where(extras.tangents[:, 3:] < 0.0, -1.0, 1.0) * np.sign(np.linalg.det(linear))
        tangents = np.concatenate([xyz, w], axis=1).astype(np.float32)
    uses_set_1 = any(uv.uv_set == 1 for uv in surface.uv_transforms)
    return tangents, extras.uvs1 if uses_set_1 else None


def _texture_array(image: Any, textures: dict[int, np.ndarray]) -> np.ndarray:
    """(h, w, 4) uint8 RGBA of a PIL ``image``, converted once per image (``textures`` by id)."""
    texture = textures.get(id(image))
    if texture is None:
        texture = textures[id(image)] = np.ascontiguousarray(np.asarray(image.convert("RGBA")))
    return texture


def _surface_material(material: Any, converted: bool, has_uvs: bool, textures: dict[int, np.ndarray],
                      extras_by_name: Mapping[str, MaterialExtras]) -> SurfaceMaterial:
    """The metallic-roughness part of a trimesh PBR ``material``: factors absent from a glTF file
    take the spec's defaults (metallic 1, roughness 1); a material ``converted`` from OBJ/MTL has
    no metalness (a matte dielectric's defaults). Maps are kept only with texture coordinates."""
    metallic = getattr(material, "metallicFactor", None)
    roughness = getattr(material, "roughnessFactor", None)
    default_metallic, default_roughness = (DEFAULT_METALLIC, DEFAULT_ROUGHNESS) if converted else (1.0, 1.0)
    emissive = getattr(material, "emissiveFactor", None)
    extras = extras_by_name.get(str(getattr(material, "name", None)), MaterialExtras())
    emissive_rgb = (np.zeros(3) if emissive is None
                    else np.asarray(emissive, np.float64).reshape(-1)[:3] * extras.emissive_strength)

    def texture(attribute: str) -> np.ndarray | None:
        image = getattr(material, attribute, None)
        return _texture_array(image, textures) if image is not None and has_uvs else None

    return SurfaceMaterial(
        uv_transforms=extras.uv_transforms,
        metallic=float(np.clip(default_metallic if metallic is None else metallic, 0.0, 1.0)),
        roughness=float(np.clip(default_roughness if roughness is None else roughness, 0.0, 1.0)),
        emissive=(float(emissive_rgb[0]), float(emissive_rgb[1]), float(emissive_rgb[2])),
        normal_scale=extras.normal_scale,
        occlusion_strength=extras.occlusion_strength,
        metallic_roughness_texture=texture("metallicRoughnessTexture"),
        normal_texture=texture("normalTexture"),
        occlusion_texture=texture("occlusionTexture"),
        emissive_texture=texture("emissiveTexture"),
    )


def _drop_nonfinite_faces(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    finite = np.isfinite(positions)
    if finite.all():
        return faces
    return faces[finite.all(axis=1)[faces].all(axis=1)]


def _linear_rgba(colors: np.ndarray) -> np.ndarray:
    """(N, 3|4) colours to linear RGBA float32: 8-bit values are sRGB-decoded, floats kept."""
    if colors.dtype == np.uint8:
        rgba = colors.astype(np.float32) / 255.0
        rgba[:, :3] = srgb_to_linear(rgba[:, :3])
    elif np.issubdtype(colors.dtype, np.integer):
        rgba = colors.astype(np.float32) / float(np.iinfo(colors.dtype).max)
    else:
        rgba = np.clip(colors.astype(np.float32), 0.0, 1.0)
    if rgba.shape[1] == 3:
        rgba = np.concatenate([rgba, np.ones((len(rgba), 1), np.float32)], axis=1)
    return np.ascontiguousarray(rgba[:, :4])


def srgb_to_linear(values: np.ndarray) -> np.ndarray:
    """sRGB-encoded 0…1 values to linear 0…1 (same shape, float32)."""
    values = np.asarray(values, dtype=np.float32)
    return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)
