"""A loaded file's objects (issue 11): the glTF node hierarchy (glTF 2.0 §3.5 nodes: names,
children, a ``matrix`` or ``translation``/``rotation``/``scale``) matched to the scene graph trimesh
built from the same file, and the file's animations (:mod:`tessera.scene.animation`). No GL.

Objects are named as trimesh names the graph's nodes: the glTF node's name, or its index when it
has none, made unique the way trimesh does it (``name_1``, …). They come in hierarchy order from
the default scene's roots (glTF's ``scene``, else the first). trimesh hangs a mesh of several
primitives under its node as extra graph nodes of random names; their geometry belongs to that node.
"""

from __future__ import annotations

import mmap
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np

from node.scene.gltf_vertices import needs_vertex_extras
from node.scene.mesh import SceneError
from tessera.scene.animation import Animation, parse_animations
from tessera.scene.gltf import GltfDocument, GltfError, read_document
from tessera.scene.graph import SceneObject
from tessera.scene.state import ObjectState, SceneStateError

GLTF_SUFFIXES = (".gltf", ".glb")


def read_gltf(path: Path) -> GltfDocument:
    """The glTF document at ``path`` with its buffers (external ones read beside it); raises
    SceneError. Buffers are read only when the file has animations or vertex attributes trimesh
    drops (:func:`node.scene.gltf_vertices.needs_vertex_extras`): nothing else here needs them.
    A GLB is mapped, not read: its BIN chunk's pages are read only where an accessor is."""
    try:
        with path.open("rb") as file:
            data: bytes | mmap.mmap = mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)
    except ValueError:   # an empty file cannot be mapped
        data = b""

    def read_uri(uri: str) -> bytes:
        try:
            return (path.parent / unquote(uri)).read_bytes()
        except OSError as exc:
            raise SceneError(f"{path}: buffer {uri!r} unreadable ({exc.strerror or exc})") from None

    try:
        outline = read_document(data, lambda uri: b"")
        if not outline.json.get("animations") and not needs_vertex_extras(outline.json):
            return outline
        return read_document(data, read_uri)
    except GltfError as exc:
        raise SceneError(f"{path}: {exc}") from None


def trimesh_node_names(nodes: list[Any]) -> dict[int, str]:
    """glTF node index → the name trimesh gives that node in its scene graph."""
    from trimesh.scene.transforms import DEFAULT_BASE_FRAME
    from trimesh.util import unique_name

    name_index: dict[str, int] = {}
    counts: dict[str | None, int] = {}
    for number, node in enumerate(nodes):
        name_index[unique_name(node.get("name", str(number)), name_index, counts=counts)] = number
    names = {number: name for name, number in name_index.items()}
    world = name_index.get(DEFAULT_BASE_FRAME)
    if world is not None:
        names[world] = unique_name(DEFAULT_BASE_FRAME, set(names.values()))
    return names


def gltf_objects(document: Mapping[str, Any]) -> tuple[list[SceneObject], dict[int, int]]:
    """The default scene's nodes as objects (hierarchy order; base state from each node's matrix or
    TRS) and glTF node index → object index. Raises SceneError for a node that cannot be an object."""
    nodes = document.get("nodes", [])
    scenes = document.get("scenes", [])
    roots = scenes[document.get("scene", 0)].get("nodes", []) if scenes else []
    names = trimesh_node_names(nodes)
    objects: list[SceneObject] = []
    index: dict[int, int] = {}
    stack = [(root, -1) for root in reversed(roots)]
    while stack:
        node, parent = stack.pop()
        if not isinstance(node, int) or not 0 <= node < len(nodes) or node in index:
            continue   # trimesh skips the same: bad references, and a node reached twice
        spec = nodes[node]
        try:
            base = _local_state(spec)
        except SceneStateError as exc:
            raise SceneError(f"glTF node {names[node]!r}: {exc}") from None
        index[node] = len(objects)
        objects.append(SceneObject(names[node], parent, base))
        stack.extend((child, index[node]) for child in reversed(spec.get("children", [])))
    return objects, index


def _local_state(node: Mapping[str, Any]) -> ObjectState:
    if "matrix" in node:
        return ObjectState.from_matrix(np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T)
    return ObjectState.from_json({key: node[key] for key in ("translation", "rotation", "scale") if key in node})


def geometry_owners(graph: Any, objects: list[SceneObject]) -> dict[str, int]:
    """Each geometry node of a trimesh scene ``graph`` → the index of the object it belongs to (its
    own, or for a primitive trimesh split off, its parent's); raises SceneError when one matches none."""
    by_name = {item.name: number for number, item in enumerate(objects)}
    parents = graph.transforms.parents
    owners = {}
    for node in graph.nodes_geometry:
        owner = by_name.get(node, by_name.get(parents.get(node)))
        if owner is None:
            raise SceneError(f"mesh node {node!r} matches no glTF node")
        owners[node] = owner
    return owners


def file_animations(document: GltfDocument, index: Mapping[int, int],
                    objects: Collection[SceneObject]) -> tuple[Animation, ...]:
    """The document's node TRS animations, targeting objects by name; raises SceneError."""
    names = [item.name for item in objects]
    try:
        return parse_animations(document, {node: names[number] for node, number in index.items()})
    except GltfError as exc:
        raise SceneError(str(exc)) from None
