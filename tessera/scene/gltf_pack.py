"""A ``.gltf`` made self-contained (issue 19: a node on another host fetches a library scene by its
content hash, one file): every buffer and image its JSON refers to by a relative URI is put
inline as a base64 ``data:`` URI (glTF 2.0 §3.9 allows both forms; the bytes are the same, so
the scene renders the same). A third larger than the files it replaces; the sha256 nodes check
is that of the packed bytes. Pure: the caller reads the referenced files.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Callable
from typing import Any
from urllib.parse import unquote

from tessera.scene.gltf import parse_json

#: MIME types of image files by suffix (glTF 2.0 §3.9.4 names PNG and JPEG; the others are extensions').
IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp",
               ".ktx2": "image/ktx2"}
BUFFER_TYPE = "application/octet-stream"


def self_contained_gltf(data: bytes, read_file: Callable[[str], bytes]) -> bytes | None:
    """The .gltf JSON ``data`` with each external buffer and image read by ``read_file`` (given the
    percent-decoded relative URI; its errors propagate) and put inline; None when nothing refers
    outside (then ``data`` is already self-contained). Raises GltfError for JSON that is not a glTF."""
    document = parse_json(data)
    references = _references(document)
    if not references:
        return None
    for item, uri, mime in references:
        payload = base64.b64encode(read_file(unquote(uri))).decode("ascii")
        item["uri"] = f"data:{mime};base64,{payload}"
    return json.dumps(document, separators=(",", ":")).encode("utf-8")


def _references(document: dict[str, Any]) -> list[tuple[dict[str, Any], str, str]]:
    """(item, uri, MIME type) of each buffer and image whose URI is not a ``data:`` URI."""
    found = []
    for kind in ("buffers", "images"):
        items = document.get(kind, [])
        for item in items if isinstance(items, list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or uri.startswith("data:"):
                continue
            if kind == "buffers":
                mime = BUFFER_TYPE
            else:
                suffix = uri[uri.rfind("."):].lower() if "." in uri else ""
                mime = item.get("mimeType") or IMAGE_TYPES.get(suffix, BUFFER_TYPE)
            found.append((item, uri, mime))
    return found
