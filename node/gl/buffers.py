"""A scene's geometry in GL buffers: uploaded a block at a time, so that from a scene cache's
mapped arrays no more than a block is copied in host memory besides what the GL keeps (the mapped
pages uploaded leave the node's resident memory: :func:`node.scene.pages.release_pages`)."""

from __future__ import annotations

import moderngl
import numpy as np

from node.scene.packing import PackedGeometry, gpu_indices
from node.scene.pages import release_pages

#: Bytes of geometry copied to the GL at a time.
UPLOAD_BLOCK_BYTES = 8 << 20


def upload_geometry(ctx: moderngl.Context, packed: PackedGeometry,
                    batch_index_bounds: np.ndarray) -> tuple[moderngl.Buffer, moderngl.Buffer]:
    """The vertex and index buffers of ``packed`` (batch b's indices are [batch_index_bounds[b],
    batch_index_bounds[b + 1])), written a block at a time: from a scene cache's mapped arrays no
    more than a block is copied in host memory besides what the GL keeps (:mod:`node.scene.cache`
    drops the mapped pages once uploaded)."""
    vertices, indices = packed.vertices, packed.indices
    vertex_buffer = ctx.buffer(reserve=max(vertices.nbytes, 1))
    index_buffer = ctx.buffer(reserve=max(indices.nbytes, 4))
    rows = max(1, UPLOAD_BLOCK_BYTES // max(1, vertices.dtype.itemsize))
    for first in range(0, len(vertices), rows):
        block = vertices[first:first + rows]
        vertex_buffer.write(np.ascontiguousarray(block), offset=first * vertices.dtype.itemsize)
        release_pages(vertices, first, first + len(block))
    scratch = np.empty(UPLOAD_BLOCK_BYTES // 4, np.uint32)
    for first in range(0, len(indices), scratch.size):
        end = min(first + scratch.size, len(indices))
        index_buffer.write(gpu_indices(indices, batch_index_bounds, packed.vertex_bounds, first, end, scratch),
                           offset=first * 4)
        release_pages(indices, first, end)
    return vertex_buffer, index_buffer
