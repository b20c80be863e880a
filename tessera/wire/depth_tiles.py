"""Depth tiles: how a hybrid tile or a sort-last layer travels from a node to the coordinator,
and what the coordinator publishes from a frame of them (issue 10; the merge itself is
:mod:`tessera.compositing.depth_merge`). Pure: bytes and arrays in, bytes and arrays out.

A depth tile is the payload of a ``TTIL`` tile message whose header carries the depth flag
(:data:`tessera.wire.protocol.DEPTH_TILE`). All integers little-endian:

- header: u32 ``version`` (sort-last: the data partition version the layer was drawn from; 0 in
  the hybrid), u16 piece count P, u8 flags (bit 0: a core follows), u8 B: how many of the pieces,
  the last ones, are blend pieces;
- the core, when flagged: u16 x, y, w, h, u32 length. A hybrid tile's core (the part no other
  tile reaches, :func:`tessera.decomposition.chunk_ownership.exclusive_rect`) is an image in the frame's tile
  codec, exactly as a sort-first tile: it needs no depth;
- P pieces: u16 x, y, w, h, u32 depth length, u32 colour length. A piece is a rect of the frame
  with depth, in the active-pixel encoding (:func:`tessera.wire.active_pixels.encode_active`) cut
  in two, each part deflated (zlib level 1): the *depth part* (width, height, runs and float32
  depths: coverage and depth, always lossless) and the *colour part* (RGB of the active pixels,
  lossless too). Cutting them lets a node report depth bytes apart from colour bytes;
- the bodies: the core's image, then each piece's depth part and colour part.

Blend pieces (sort-last: the node's blended fragments, :class:`tessera.compositing.layers.BlendLayer`)
are its K layers in order, all over one rect, each encoded the same way: active where an m-th
nearest fragment lies, with its depth, the colour part the premultiplied RGB of the m nearest's
accumulation followed by its alpha. They may overlap the other pieces; the coordinator lays them
over the merged frame.

Pieces with no active pixel are not sent; a sort-last node with nothing in view sends no piece.
The coordinator checks every rect against what it expects of the tile (:func:`read_depth_tile`:
the pieces inside the tile's read-back rect, disjoint, the core inside the tile and holding the
part no other tile reaches) and inflates
no more than a piece's size allows, so a malformed or hostile tile is a ProtocolError, never a
bomb.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tessera.compositing.layers import FAR, BlendLayer, DepthLayer, split_layer
from tessera.geometry import Rect
from tessera.wire.active_pixels import DepthCodecError, decode_active, encode_active
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import ProtocolError

_HEADER = struct.Struct("<IHBB")
_CORE = struct.Struct("<HHHHI")
_PIECE = struct.Struct("<HHHHII")
_CORE_FLAG = 0x01
#: Most pieces a depth tile may hold besides its blend pieces: a hybrid tile's ring is at most four
#: rects (a sort-last layer is one).
MAX_PIECES = 4
#: Most blend pieces (peeled layers of blended fragments) a depth tile may hold.
MAX_BLEND_PIECES = 8
#: zlib level of the piece parts: level 1 deflates the runs and the colour of active pixels well
#: at a fraction of level 6's time (measured with bench.compose).
DEFLATE_LEVEL = 1


@dataclass(frozen=True, slots=True)
class DepthTileCounts:
    """What a depth tile carries: pixels sent with colour (the core's and the pieces' active ones)
    and with depth (the pieces' active ones), and the bytes of each (the core image counts as
    colour; a piece's depth part, runs included, as depth)."""

    color_px: int
    color_bytes: int
    depth_px: int
    depth_bytes: int

    def as_stats(self) -> dict[str, int]:
        return {"color_px": self.color_px, "color_bytes": self.color_bytes, "depth_px": self.depth_px,
                "depth_bytes": self.depth_bytes}


@dataclass(frozen=True, eq=False)
class DecodedDepthTile:
    """A depth tile as the coordinator keeps it: the ``version`` it names, its ``core`` (rect and
    the image bytes, forwarded to viewers as they are; None: no core) and its pieces decoded into
    ``layers`` (with the slot they merge at) and ``blends`` (none, or one blend layer)."""

    version: int
    core: tuple[Rect, bytes] | None
    layers: tuple[DepthLayer, ...]
    blends: tuple[BlendLayer, ...] = ()

    @property
    def extent(self) -> Rect | None:
        """The smallest rect of the frame holding all the tile carries (core, pieces, blend
        layers): where its node drew something; None: nowhere."""
        rects = [layer.rect for layer in self.layers] + [blend.rect for blend in self.blends]
        if self.core is not None:
            rects.append(self.core[0])
        if not rects:
            return None
        x, y = min(r.x for r in rects), min(r.y for r in rects)
        return Rect(x, y, max(r.x1 for r in rects) - x, max(r.y1 for r in rects) - y)


def encode_depth_tile(layer: DepthLayer | None, core: Rect | None, codec: Codec, quality: int,
                      version: int = 0, blend: BlendLayer | None = None) -> tuple[bytes, DepthTileCounts]:
    """The payload of a rendered ``layer`` (None: nothing drawn, no piece) whose ``core`` (inside
    the layer's rect; None: all of it carries depth) goes as an image in ``codec`` (JPEG
    ``quality``) and the rest as pieces, and of its ``blend`` layer (None: no blended fragments);
    with the counts of what it carries."""
    pieces: list[DepthLayer] = []
    core_bytes = b""
    if layer is not None:
        pieces, core_pixels = split_layer(layer, core)
        if core_pixels is not None:
            core_bytes = encode(core_pixels, codec, quality)
    parts, entries = [core_bytes], []
    depth_px = depth_bytes = color_bytes = 0
    blend_layers = 0 if blend is None else blend.depth.shape[0]
    if blend is not None:
        pieces = [*pieces, *(DepthLayer(blend.rect, blend.color[m], blend.depth[m], 0) for m in range(blend_layers))]
    for number, piece in enumerate(pieces):
        active = int(np.count_nonzero(piece.depth < FAR))
        is_blend = number >= len(pieces) - blend_layers
        if active == 0 and not is_blend:
            continue
        depth_part, color_part = _active_parts(piece)
        if is_blend:
            assert blend is not None
            m = number - (len(pieces) - blend_layers)
            color_part += blend.alpha[m][blend.depth[m] < FAR].tobytes()
        depth_zip, color_zip = zlib.compress(depth_part, DEFLATE_LEVEL), zlib.compress(color_part, DEFLATE_LEVEL)
        rect = piece.rect
        entries.append(_PIECE.pack(rect.x, rect.y, rect.w, rect.h, len(depth_zip), len(color_zip)))
        parts += [depth_zip, color_zip]
        depth_px += active
        depth_bytes += len(depth_zip)
        color_bytes += len(color_zip)
    head = [_HEADER.pack(version, len(entries), _CORE_FLAG if core_bytes else 0, blend_layers)]
    if core_bytes:
        assert core is not None
        head.append(_CORE.pack(core.x, core.y, core.w, core.h, len(core_bytes)))
    core_px = core.area if core is not None and core_bytes else 0
    counts = DepthTileCounts(depth_px + core_px, color_bytes + len(core_bytes), depth_px, depth_bytes)
    return b"".join([*head, *entries, *parts]), counts


def _active_parts(piece: DepthLayer) -> tuple[bytes, bytes]:
    """The active-pixel encoding of ``piece`` cut into its depth part (header, runs, depths) and
    its colour part."""
    data = encode_active(piece.depth, piece.color)
    pairs = struct.unpack_from("<I", data, 4)[0]
    active = (len(data) - 8 - 8 * pairs) // 7
    cut = 8 + 8 * pairs + 4 * active
    return data[:cut], data[cut:]


def read_depth_tile(payload: bytes, bound: Rect, core_range: tuple[Rect | None, Rect] | None,
                    slot: int) -> DecodedDepthTile:
    """Parse, check and decode a depth tile whose pieces must lie inside ``bound`` (a hybrid tile's
    read-back rect, or the whole frame) and whose core must hold the first rect of ``core_range``
    (None: nothing; the core may then be left out) and lie inside the second (a hybrid tile's
    rect); ``core_range`` None: no core allowed (sort-last). Its layers merge at ``slot``. The
    core's image is left to the caller to check (it is a tile image in the frame's codec). Raises
    ProtocolError naming what is wrong."""
    data = memoryview(payload)
    if len(data) < _HEADER.size:
        raise ProtocolError(f"depth tile of {len(data)} bytes has no header")
    version, count, flags, blended = _HEADER.unpack_from(data)
    if flags & ~_CORE_FLAG:
        raise ProtocolError(f"depth tile flags {flags:#x} unknown")
    if blended > min(count, MAX_BLEND_PIECES) or count - blended > MAX_PIECES:
        raise ProtocolError(f"depth tile of {count} pieces, {blended} of them blend pieces; at most {MAX_PIECES} "
                            f"and {MAX_BLEND_PIECES}")
    offset = _HEADER.size
    sent_core: tuple[Rect, int] | None = None
    if flags & _CORE_FLAG:
        if len(data) < offset + _CORE.size:
            raise ProtocolError("depth tile ends inside its core entry")
        x, y, w, h, length = _CORE.unpack_from(data, offset)
        sent_core = (Rect(x, y, w, h), length)
        offset += _CORE.size
    core = None if sent_core is None else sent_core[0]
    _check_core(core, core_range)
    entries = []
    for _ in range(count):
        if len(data) < offset + _PIECE.size:
            raise ProtocolError("depth tile ends inside its piece table")
        x, y, w, h, depth_length, color_length = _PIECE.unpack_from(data, offset)
        entries.append((Rect(x, y, w, h), depth_length, color_length))
        offset += _PIECE.size
    _check_rects([rect for rect, _, _ in entries[:count - blended]], bound, core)
    blend_rects = {rect for rect, _, _ in entries[count - blended:]}
    if len(blend_rects) > 1 or any(not _inside(rect, bound) for rect in blend_rects):
        raise ProtocolError(f"depth tile blend pieces {sorted(r.as_list() for r in blend_rects)} are not one rect "
                            f"inside {bound.as_list()}")
    body = offset + (sent_core[1] if sent_core else 0)
    if len(data) != body + sum(d + c for _, d, c in entries):
        raise ProtocolError(f"depth tile of {len(data)} bytes; its tables say "
                            f"{body + sum(d + c for _, d, c in entries)}")
    layers, peeled = [], []
    for number, (rect, depth_length, color_length) in enumerate(entries):
        is_blend = number >= count - blended
        depth_part = _inflate(data[body:body + depth_length], 8 + 8 * ((rect.area + 1) // 2 + 1) + 4 * rect.area)
        body += depth_length
        color_part = _inflate(data[body:body + color_length], (4 if is_blend else 3) * rect.area)
        body += color_length
        alpha_part = b""
        if is_blend:
            cut = len(color_part) * 3 // 4
            color_part, alpha_part = color_part[:cut], color_part[cut:]
        try:
            depth, color = decode_active(depth_part + color_part)
        except DepthCodecError as exc:
            raise ProtocolError(f"depth tile piece {rect.as_list()}: {exc}") from None
        if depth.shape != (rect.h, rect.w):
            raise ProtocolError(f"depth tile piece {rect.as_list()} holds a {depth.shape[1]}x{depth.shape[0]} layer")
        if not is_blend:
            layers.append(DepthLayer(rect, color, depth, slot))
            continue
        active = depth < FAR
        if len(alpha_part) != int(active.sum()):
            raise ProtocolError(f"depth tile blend piece {rect.as_list()} has {len(alpha_part)} alpha values for "
                                f"{int(active.sum())} pixels")
        alpha = np.zeros(depth.shape, np.uint8)
        alpha[active] = np.frombuffer(alpha_part, np.uint8)
        peeled.append((depth, color, alpha))
    core_entry = None
    if sent_core is not None:
        start = _HEADER.size + _CORE.size + _PIECE.size * count
        core_entry = (sent_core[0], bytes(data[start:start + sent_core[1]]))
    blends: tuple[BlendLayer, ...] = ()
    if peeled:
        depths, colors, alphas = (np.stack(parts) for parts in zip(*peeled, strict=True))
        blends = (BlendLayer(entries[-1][0], colors, alphas, depths, slot),)
    return DecodedDepthTile(version, core_entry, tuple(layers), blends)


def _check_core(core: Rect | None, core_range: tuple[Rect | None, Rect] | None) -> None:
    """``core`` (None: none sent) holds ``core_range[0]`` and lies inside ``core_range[1]``."""
    least, most = (None, None) if core_range is None else core_range
    shown = None if core is None else core.as_list()
    if core is None:
        if least is not None:
            raise ProtocolError(f"depth tile has no core; it needs one holding {least.as_list()}")
        return
    if most is None or not _inside(core, most) or (least is not None and not _inside(least, core)):
        raise ProtocolError(f"depth tile core {shown} is not inside the tile {None if most is None else most.as_list()}"
                            f" or does not hold {None if least is None else least.as_list()}")


def _inside(inner: Rect, outer: Rect) -> bool:
    return outer.x <= inner.x and outer.y <= inner.y and inner.x1 <= outer.x1 and inner.y1 <= outer.y1 \
        and inner.w > 0 and inner.h > 0


def _check_rects(pieces: Sequence[Rect], bound: Rect, core: Rect | None) -> None:
    """Pieces non-empty, inside ``bound``, disjoint from each other and from ``core``."""
    for number, rect in enumerate(pieces):
        if not _inside(rect, bound):
            raise ProtocolError(f"depth tile piece {rect.as_list()} is empty or outside {bound.as_list()}")
        others = [*pieces[:number], *([core] if core is not None else [])]
        if any(rect.intersection_area(other) for other in others):
            raise ProtocolError(f"depth tile piece {rect.as_list()} overlaps another piece or the core")


def _inflate(data: memoryview, limit: int) -> bytes:
    """``data`` inflated, refusing more than ``limit`` bytes of output or anything after the stream."""
    inflater = zlib.decompressobj()
    try:
        out = inflater.decompress(data, limit + 1)
    except zlib.error as exc:
        raise ProtocolError(f"depth tile piece does not inflate: {exc}") from None
    if len(out) > limit or not inflater.eof or inflater.unused_data:
        raise ProtocolError(f"depth tile piece inflates to more than {limit} bytes or is cut short")
    return out
