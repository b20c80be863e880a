"""Depth layers: what a node reads back with depth, the conventions every node and the compositor
share, and how a hybrid tile is cut into pieces. Seed 000 §4.4 (the hybrid partition: each tile's border strip merged
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
(premultiplied, in draw order) and how much they let through. The merge
(:func:`tessera.compositing.depth_merge.merge_by_depth`) lays over each pixel of the merged frame
the m fragments in front of it, as GL blends them over the opaque frame: exact
up to a level or two of rounding (GL rounds after each fragment), with at most K blended
fragments of a node in front of its own layer at a pixel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tessera.geometry import Rect

#: Window depth of an empty pixel: depth buffers are cleared to it.
FAR = np.float32(1.0)


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
    (round(v × 255)), the colour the merge paints where no layer drew."""
    values = np.asarray(rgb, dtype=np.float64)
    if values.shape != (3,) or not np.all((values >= 0.0) & (values <= 1.0)):
        raise ValueError(f"background must be three numbers in [0, 1], got {list(rgb)}")
    return np.rint(values * 255.0).astype(np.uint8)


def split_layer(layer: DepthLayer, core: Rect | None) -> tuple[list[DepthLayer], np.ndarray | None]:
    """``layer`` as a hybrid tile sends it: the pieces that carry depth — its rect minus ``core``
    (frame coordinates, inside the rect; None: no core), at most four rects (top and bottom bands
    full width, left and right ones between), each with the layer's slot — and the core's colour
    (core.h, core.w, 3) uint8 (None without a core), an exclusive region of
    :func:`tessera.compositing.depth_merge.merge_by_depth`. The
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


def pixel_view(color: np.ndarray) -> np.ndarray:
    """(h, w) view of (h, w, 3) uint8 ``color`` (made contiguous) with one 3-byte item per pixel:
    masked copies and boolean indexing then move whole pixels (several times faster than
    broadcasting a mask over the colour axis)."""
    return np.ascontiguousarray(color).view("V3")[..., 0]
