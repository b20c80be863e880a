"""Active-pixel encoding of a depth layer (IceT's), the form depth travels in between nodes and the
coordinator.

Codec (IceT's active-pixel encoding): the pixels of a layer in raster order, as alternating runs of
inactive and active pixels; only active pixels carry depth (float32, bit-exact) and colour (RGB).
Little-endian layout: width, height (uint16 each), run pairs R (uint32); R × (inactive count,
active count) uint32, the last pair's active count 0; A float32 depths; A × 3 uint8 colours, where A
is the summed active counts. Pure numpy: no per-pixel Python anywhere.
"""

from __future__ import annotations

import struct

import numpy as np

from tessera.compositing.layers import FAR, pixel_view

_HEADER = struct.Struct("<HHI")
_MAX_SIDE = 0xFFFF


class DepthCodecError(ValueError):
    """Bytes that are not a well-formed active-pixel layer."""


def encode_active(depth: np.ndarray, color: np.ndarray) -> bytes:
    """The active-pixel encoding (module docstring) of ``depth`` (h, w) float32 and ``color``
    (h, w, 3) uint8: runs over raster order, depth and colour of the pixels whose depth is below
    :data:`FAR` only."""
    if depth.dtype != np.float32 or color.dtype != np.uint8 or color.shape != (*depth.shape, 3) or depth.ndim != 2:
        raise ValueError(f"expected (h, w) float32 depth and (h, w, 3) uint8 colour, got {depth.shape} "
                         f"{depth.dtype} and {color.shape} {color.dtype}")
    height, width = depth.shape
    if width > _MAX_SIDE or height > _MAX_SIDE:
        raise ValueError(f"a layer is at most {_MAX_SIDE} pixels a side, got {width}x{height}")
    flat = np.ascontiguousarray(depth).reshape(-1)
    active = flat < FAR
    edges = np.flatnonzero(np.diff(active, prepend=False, append=False))
    starts, ends = edges[0::2], edges[1::2]
    gaps = starts - np.concatenate(([0], ends[:-1]))
    tail = flat.size - (int(ends[-1]) if ends.size else 0)
    runs = np.stack([np.append(gaps, tail), np.append(ends - starts, 0)], axis=1).astype("<u4")
    return b"".join((_HEADER.pack(width, height, runs.shape[0]), runs.tobytes(),
                     flat[active].astype("<f4").tobytes(), pixel_view(color).reshape(-1)[active].tobytes()))


def decode_active(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """``(depth, color)`` from :func:`encode_active` bytes: (h, w) float32 with :data:`FAR` at
    inactive pixels and (h, w, 3) uint8, black there (the colour no one looks at). Depth and the
    active pixels' colour come back bit-exact; raises DepthCodecError for malformed bytes."""
    if len(data) < _HEADER.size:
        raise DepthCodecError(f"active-pixel layer of {len(data)} bytes has no header")
    width, height, pairs = _HEADER.unpack_from(data)
    pixels = width * height
    runs_end = _HEADER.size + 8 * pairs
    if pairs < 1 or pairs > (pixels + 1) // 2 + 1 or len(data) < runs_end:
        raise DepthCodecError(f"active-pixel layer {width}x{height}: {pairs} run pairs do not fit")
    runs = np.frombuffer(data, "<u4", 2 * pairs, _HEADER.size).astype(np.int64)
    active_count = int(runs[1::2].sum())
    if int(runs.sum()) != pixels or runs[-1] != 0:
        raise DepthCodecError(f"active-pixel layer {width}x{height}: runs cover {int(runs.sum())} pixels")
    if len(data) != runs_end + 7 * active_count:
        raise DepthCodecError(f"active-pixel layer {width}x{height} with {active_count} active pixels needs "
                              f"{runs_end + 7 * active_count} bytes, got {len(data)}")
    values = np.frombuffer(data, "<f4", active_count, runs_end)
    if not np.all((values >= 0.0) & (values < FAR)):
        raise DepthCodecError("active-pixel depth must lie in [0, 1)")
    active = np.repeat(np.tile(np.array([False, True]), pairs), runs).reshape(height, width)
    depth = np.full((height, width), FAR, np.float32)
    depth[active] = values
    color = np.zeros((height, width, 3), np.uint8)
    pixel_view(color)[active] = np.frombuffer(data, "V3", active_count, runs_end + 4 * active_count)
    return depth, color
