"""Small scene files the scene library tests upload and serve: one triangle as PLY and as glTF."""

from __future__ import annotations

import base64
import json

import numpy as np

#: One triangle as ASCII PLY: the smallest file that loads as a scene.
TRIANGLE_PLY = b"""ply
format ascii 1.0
element vertex 3
property float x
property float y
property float z
element face 1
property list uchar int vertex_indices
end_header
0 0 0
1 0 0
0 1 0
3 0 1 2
"""


def triangle_gltf(buffer_uri: str | None = None, image_uri: str | None = None) -> bytes:
    """A glTF of one triangle, its buffer as a data: URI unless ``buffer_uri`` is given, with an
    image of ``image_uri`` if given."""
    data = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4").tobytes()
    document = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, 0], "max": [1, 1, 0]}],
        "bufferViews": [{"buffer": 0, "byteLength": len(data)}],
        "buffers": [{"byteLength": len(data),
                     "uri": buffer_uri or "data:application/octet-stream;base64," + base64.b64encode(data).decode()}],
    }
    if image_uri is not None:
        document["images"] = [{"uri": image_uri}]
    return json.dumps(document).encode()
