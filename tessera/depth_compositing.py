"""Depth compositing: colour + depth layers merged into one frame, and the active-pixel run-length
codec the layers travel in. Seed 000 §4.4 (the hybrid partition: each tile's border strip merged
"by Z-buffer") and the sort-last database decomposition both end here; one compositor serves both.

Conventions every node and the compositor share (IceT's, seed 000 leaves them open):

- Depth is window depth as 32-bit floats in [0, 1], read back from GL with the one projection (the
  full frame's camera, viewport and near/far) every node uses, so equal surfaces give equal bits.
- Depth buffers are cleared to far, :data:`FAR` = 1.0, and drawn with ``GL_LESS``: no fragment
  ever lands at 1.0, so 1.0 means "nothing drawn here" (an inactive pixel).
- The smaller depth wins. Equal depths (two layers drew the same surface, or a coplanar overlap)
  go to the lower ``slot``, whatever order the layers arrive in.
- The background is applied once, at the end, where no layer drew: a layer's colour where its
  depth is far is never looked at (and the codec does not carry it).
- A hybrid tile's core, which no other tile reaches, travels as colour alone (as drawn, like a
  sort-first tile) and is pasted after the merge (:func:`split_layer`); only its strips carry
  depth, as in the seed's Fig. 4.6.
- Integer depth (a 24-bit depth buffer read as integers) is refused by :class:`DepthLayer`;
  :func:`depth_from_integer` converts it explicitly.

Blended geometry (glTF ``BLEND``) writes no depth, so merging by depth is exact for opaque and
alpha-masked geometry only: a blended surface keeps its colour only if the layer that drew it also
wins on the depth behind it. A node can send its blended fragments apart instead, as a
:class:`BlendLayer`: the depths of the nearest K, and for each m ≤ K what the m nearest add
(premultiplied, in draw order) and how much they let through. :func:`composite` lays over each
pixel of the merged frame the m fragments in front of it, as GL blends them over the opaque frame:
exact up to a level or two of rounding (GL rounds after each fragment), with at most K blended
fragments of a node in front of its own layer at a pixel.

Codec (IceT's active-pixel encoding): the pixels of a layer in raster order, as alternating runs of
inactive and active pixels; only active pixels carry depth (float32, bit-exact) and colour (RGB).
Little-endian layout: width, height (uint16 each), run pairs R (uint32); R × (inactive count,
active count) uint32, the last pair's active count 0; A float32 depths; A × 3 uint8 colours, where A
is the summed active counts. Pure numpy: no per-pixel Python anywhere.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from tessera.geometry import Rect

#: Window depth of an empty pixel: depth buffers are cleared to it.
FAR = np.float32(1.0)
_HEADER = struct.Struct("<HHI")
_MAX_SIDE = 0xFFFF


class DepthCodecError(ValueError):
    """Bytes that are not a well-formed active-pixel layer."""


@dataclass(frozen=True, eq=False)
class DepthLayer:
    """One node's read-back of the ``rect`` part of the frame: ``color`` (rect.h, rect.w, 3) uint8
    and ``depth`` (rect.h, rect.w) float32 window depth in [0, 1] (:data:`FAR` where nothing was
    drawn), row 0 at the top; ``slot`` ≥ 0 breaks depth ties (lower wins). Raises TypeError for
    depth that is not float32 (convert integer depth with :func:`depth_from_integer`) and
    ValueError for wrong shapes or depth outside [0, 1] (NaN included)."""

    rect: Rect
    color: np.ndarray
    depth: np.ndarray
    slot: int

    def __post_init__(self) -> None:
        shape = (self.rect.h, self.rect.w)
        if self.depth.dtype != np.float32:
            raise TypeError(f"layer depth must be float32 window depth, got {self.depth.dtype}; convert integer "
                            "depth with depth_from_integer")
        if self.color.dtype != np.uint8:
            raise TypeError(f"layer colour must be uint8, got {self.color.dtype}")
        if self.depth.shape != shape or self.color.shape != (*shape, 3):
            raise ValueError(f"layer {self.rect.as_list()} needs depth {shape} and colour {(*shape, 3)}, got "
                             f"{self.depth.shape} and {self.color.shape}")
        if self.depth.size and not (self.depth.min() >= 0.0 and self.depth.max() <= FAR):
            raise ValueError("layer depth must lie in [0, 1]")
        if self.slot < 0:
            raise ValueError(f"layer slot must be >= 0, got {self.slot}")


@dataclass(frozen=True, eq=False)
class BlendLayer:
    """One node's blended fragments over ``rect``, peeled into K layers: ``depth`` (K, rect.h,
    rect.w) float32 the m-th nearest fragment's window depth (:data:`FAR` where there are fewer
    than m), and ``color`` (K, rect.h, rect.w, 3) uint8 and ``alpha`` (K, rect.h, rect.w) uint8:
    the m nearest accumulated in draw order into a cleared buffer, as GL's ``SRC_ALPHA,
    ONE_MINUS_SRC_ALPHA`` blending (alpha: ``ONE, ONE_MINUS_SRC_ALPHA``) gives them,
    premultiplied. ``slot`` orders the blend layers of several nodes (lower first)."""

    rect: Rect
    color: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray
    slot: int

    def __post_init__(self) -> None:
        shape = (self.depth.shape[0] if self.depth.ndim == 3 else -1, self.rect.h, self.rect.w)
        if self.depth.shape != shape or self.color.shape != (*shape, 3) or self.alpha.shape != shape or \
                self.color.dtype != np.uint8 or self.alpha.dtype != np.uint8 or self.depth.dtype != np.float32:
            raise ValueError(f"blend layer {self.rect.as_list()} needs (K, {self.rect.h}, {self.rect.w}) float32 "
                             "depth and uint8 alpha, and uint8 colour with 3 channels more")


def depth_from_integer(values: np.ndarray, bits: int) -> np.ndarray:
    """``values`` (any shape) of a ``bits``-bit integer depth buffer as float32 window depth in
    [0, 1]: value / (2^bits − 1), so the buffer's clear value 2^bits − 1 becomes exactly :data:`FAR`.
    Raises TypeError for non-integer input and ValueError for values out of range."""
    values = np.asarray(values)
    if not np.issubdtype(values.dtype, np.integer):
        raise TypeError(f"integer depth expected, got {values.dtype}")
    if not 1 <= bits <= 32:
        raise ValueError(f"depth bits must be in [1, 32], got {bits}")
    top = (1 << bits) - 1
    if values.size and (values.min() < 0 or values.max() > top):
        raise ValueError(f"{bits}-bit depth must lie in [0, {top}]")
    return (values.astype(np.float64) / top).astype(np.float32)


def background_pixel(rgb: Sequence[float]) -> np.ndarray:
    """(3,) uint8 of a linear-unit ``rgb`` clear colour as GL stores it in an 8-bit buffer
    (round(v × 255)), the colour :func:`composite` paints where no layer drew."""
    values = np.asarray(rgb, dtype=np.float64)
    if values.shape != (3,) or not np.all((values >= 0.0) & (values <= 1.0)):
        raise ValueError(f"background must be three numbers in [0, 1], got {list(rgb)}")
    return np.rint(values * 255.0).astype(np.uint8)


def composite(layers: Iterable[DepthLayer], size: tuple[int, int], background: np.ndarray,
              exclusive: Iterable[tuple[Rect, np.ndarray]] = (), blends: Iterable[BlendLayer] = ()) -> np.ndarray:
    """(h, w, 3) uint8: ``layers`` merged by depth into a ``size`` = (w, h) frame, ``background``
    (3,) uint8 where none drew, the ``blends`` laid over it in slot order (at each pixel the
    accumulation of the m fragments in front of the merged depth: its colour + (255 − alpha) / 255
    × what is there, rounded), then the ``exclusive`` (rect, (rect.h, rect.w, 3) uint8 colour)
    pasted as they are: regions only one node drew (the hybrid's tile cores,
    :func:`tessera.chunk_ownership.exclusive_rect`), which travel without depth and which the
    layers leave inactive. Layers are merged in slot order with a strict depth test, so a tie goes
    to the lower slot whatever order they came in; layers that share a slot (the pieces of one
    node's layer, :func:`split_layer`) must not overlap. Raises ValueError for a layer or region
    outside the frame or overlapping layers of one slot. The frame starts as the background, then
    O(summed layer pixels): depth by ``minimum``, colour by one masked copy of whole pixels
    (:func:`_pixels`)."""
    width, height = size
    if width <= 0 or height <= 0:
        raise ValueError(f"frame size must be positive, got {width}x{height}")
    ordered = sorted(layers, key=lambda item: item.slot)
    by_slot: dict[int, list[Rect]] = {}
    for layer in ordered:
        same = by_slot.setdefault(layer.slot, [])
        if any(layer.rect.intersection_area(other) for other in same):
            raise ValueError(f"layers of slot {layer.slot} overlap: each node's layer needs its own slot")
        same.append(layer.rect)
    depth = np.full((height, width), FAR, np.float32)
    color = np.empty((height, width, 3), np.uint8)
    color[0] = np.asarray(background, np.uint8)
    color[1:] = color[0]   # whole rows: broadcasting the pixel over (h, w) is ~100x slower
    pixels = _pixels(color)
    for layer in ordered:
        rect = layer.rect
        if rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
            raise ValueError(f"layer {rect.as_list()} lies outside the {width}x{height} frame")
        window = np.s_[rect.y:rect.y1, rect.x:rect.x1]
        wins = layer.depth < depth[window]
        np.minimum(depth[window], layer.depth, out=depth[window])
        np.copyto(pixels[window], _pixels(layer.color), where=wins)
    for blend in sorted(blends, key=lambda item: item.slot):
        rect = blend.rect
        if rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height:
            raise ValueError(f"blend layer {rect.as_list()} lies outside the {width}x{height} frame")
        window = np.s_[rect.y:rect.y1, rect.x:rect.x1]
        count = (blend.depth < depth[window][None]).sum(axis=0)
        rows, columns = np.nonzero(count)
        layer = count[rows, columns] - 1
        under = color[window][rows, columns].astype(np.float32)
        through = (255.0 - blend.alpha[layer, rows, columns].astype(np.float32))[:, None] / np.float32(255.0)
        mixed = blend.color[layer, rows, columns].astype(np.float32) + through * under
        color[window][rows, columns] = np.minimum(np.rint(mixed), 255.0).astype(np.uint8)
    for rect, region in exclusive:
        if rect.x < 0 or rect.y < 0 or rect.x1 > width or rect.y1 > height or region.shape != (rect.h, rect.w, 3):
            raise ValueError(f"exclusive region {rect.as_list()} with colour {region.shape} does not fit the "
                             f"{width}x{height} frame")
        color[rect.y:rect.y1, rect.x:rect.x1] = region
    return color


def split_layer(layer: DepthLayer, core: Rect | None) -> tuple[list[DepthLayer], np.ndarray | None]:
    """``layer`` as a hybrid tile sends it: the pieces that carry depth — its rect minus ``core``
    (frame coordinates, inside the rect; None: no core), at most four rects (top and bottom bands
    full width, left and right ones between), each with the layer's slot — and the core's colour
    (core.h, core.w, 3) uint8 (None without a core), an exclusive region of :func:`composite`. The
    core goes as drawn, as a sort-first tile does: where nothing was drawn it holds the node's clear
    colour, which is the frame's background on every node."""
    rect = layer.rect
    if core is None:
        return [layer], None

    def window(piece: Rect) -> tuple[slice, slice]:
        return slice(piece.y - rect.y, piece.y1 - rect.y), slice(piece.x - rect.x, piece.x1 - rect.x)

    strips = [DepthLayer(piece, layer.color[window(piece)], layer.depth[window(piece)], layer.slot)
              for piece in ring_rects(rect, core)]
    return strips, np.ascontiguousarray(layer.color[window(core)])


def ring_rects(rect: Rect, core: Rect) -> list[Rect]:
    """``rect`` minus ``core`` (inside it) as at most four disjoint non-empty rects: the top and
    bottom bands full width, the left and right ones between. Raises ValueError for a core that
    is not inside the rect."""
    if core.x < rect.x or core.y < rect.y or core.x1 > rect.x1 or core.y1 > rect.y1:
        raise ValueError(f"core {core.as_list()} is not inside the layer {rect.as_list()}")
    pieces = [Rect(rect.x, rect.y, rect.w, core.y - rect.y), Rect(rect.x, core.y1, rect.w, rect.y1 - core.y1),
              Rect(rect.x, core.y, core.x - rect.x, core.h), Rect(core.x1, core.y, rect.x1 - core.x1, core.h)]
    return [piece for piece in pieces if piece.w > 0 and piece.h > 0]


def _pixels(color: np.ndarray) -> np.ndarray:
    """(h, w) view of (h, w, 3) uint8 ``color`` (made contiguous) with one 3-byte item per pixel:
    masked copies and boolean indexing then move whole pixels (several times faster than
    broadcasting a mask over the colour axis)."""
    return np.ascontiguousarray(color).view("V3")[..., 0]


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
                     flat[active].astype("<f4").tobytes(), _pixels(color).reshape(-1)[active].tobytes()))


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
    _pixels(color)[active] = np.frombuffer(data, "V3", active_count, runs_end + 4 * active_count)
    return depth, color
