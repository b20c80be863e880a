"""Binary wire format between nodes, coordinator and viewers (sans-I/O: bytes in, bytes out).

Binary WebSocket messages start with a magic:

* ``TTIL`` tile result, node → coordinator: :class:`TileHeader` + one encoded image. Its u16 at
  offset 6 is the low 16 bits of the scene state version the tile was rendered with (issue 11: a
  frame's tiles all show one state; 0 for a static scene, as before). Its codec byte with
  :data:`DEPTH_TILE` set (issue 10: the hybrid and sort-last modes) marks a depth tile, whose
  payload is a :mod:`tessera.wire.depth_tiles` layer (its core image in the codec of the low bits);
  nodes send one only when a ``render`` message asks for depth, which the coordinator does only
  of nodes whose ``hello`` says they can (``capabilities.depth``): the flag extends version 2
  without changing a byte of what older nodes and viewers exchange.
* ``TFRM`` complete frame, coordinator → viewer: a 24-byte frame header (flags: bit 0 = the
  still frame — the converged progressive still; bits 1–7 = the samples a progressive still's
  frame holds (issue 20: 1…127; 0 = a frame that is not accumulated, as every frame of a
  coordinator without ``--still-samples``; viewers that read bit 0 alone see a refinement frame
  as an interactive one); ``input_seq``: the viewer's newest input sequence number the frame
  accounts for, 0 = none), then one :class:`FrameTileEntry` per tile (``node``: the rendering node's slot, a
  small index reused after a node leaves, u16; :data:`NO_NODE_SLOT` for a tile no one node
  rendered), then the tiles' encoded images in the same order.

All integers little-endian. Text messages (JSON control messages) are catalogued in
:mod:`tessera.wire.messages`; :data:`PROTOCOL_VERSION` covers both.

``web/protocol.js`` mirrors these constants and layouts; one golden byte string, tested in
``tests/test_protocol_golden.py`` and ``tests/js/protocol.test.mjs``, pins both sides.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass

from tessera.geometry import Rect
from tessera.wire.codec import Codec

PROTOCOL_VERSION = 2
TILE_MAGIC = b"TTIL"
FRAME_MAGIC = b"TFRM"
#: Per-tile phases a node measures, in pipeline order (milliseconds): the tile header's times,
#: then ``tile_sent.send_ms``. The stats, the metrics and the viewer's panel use these names.
NODE_PHASES = ("render", "readback", "encode", "send")
#: A frame tile entry's ``node`` when no one node rendered the tile: a sort-last frame merged on
#: the coordinator from every node's layer, or a tile whose node has left since.
NO_NODE_SLOT = 0xFFFF

_TILE_HEADER = struct.Struct("<4sBBHIIIIIIfffI")
_FRAME_HEADER = struct.Struct("<4sBBHIIII")
_INPUT_SEQ_OFFSET = 20
#: The bits of a scene state version a tile header carries.
STATE_TAG_MASK = 0xFFFF
#: Frame header flag: the lossless still frame shown once motion stopped.
FRAME_STILL = 0x01
#: Frame header flags bits 1–7: the samples a progressive still's frame holds (0: not accumulated).
FRAME_SAMPLES_SHIFT = 1
FRAME_SAMPLES_MAX = 0x7F
#: Tile header codec flag: the payload is a depth tile (:mod:`tessera.wire.depth_tiles`).
DEPTH_TILE = 0x80
_FRAME_TILE = struct.Struct("<IIIIBBHI")


class ProtocolError(ValueError):
    """A peer sent something that does not follow the protocol; the text says what."""


@dataclass(frozen=True, slots=True)
class TileHeader:
    """A rendered tile: which frame and tile, where, how encoded, the node's phase times (ms) and
    ``state``, the scene state version it shows (:func:`state_tag`: its low 16 bits); ``depth``:
    a depth tile (:data:`DEPTH_TILE`), ``codec`` then being its core's."""

    frame_id: int
    tile_id: int
    rect: Rect
    codec: Codec
    render_ms: float
    readback_ms: float
    encode_ms: float
    state: int = 0
    depth: bool = False


def state_tag(version: int | None) -> int:
    """What a tile header carries of scene state version ``version`` (None: no state, 0). Versions a
    frame in flight may show lie within the state log's history, far fewer than 2¹⁶ apart."""
    return 0 if version is None else version & STATE_TAG_MASK


def pack_tile(header: TileHeader, payload: bytes) -> bytes:
    """Binary tile message: 48-byte header + encoded image."""
    r = header.rect
    codec = int(header.codec) | (DEPTH_TILE if header.depth else 0)
    head = _TILE_HEADER.pack(
        TILE_MAGIC, PROTOCOL_VERSION, codec, state_tag(header.state), header.frame_id, header.tile_id,
        r.x, r.y, r.w, r.h, header.render_ms, header.readback_ms, header.encode_ms, len(payload),
    )
    return head + payload


def unpack_tile(message: bytes) -> tuple[TileHeader, memoryview]:
    """Parse a binary tile message; raises ProtocolError on anything malformed."""
    if len(message) < _TILE_HEADER.size:
        raise ProtocolError(f"tile message of {len(message)} bytes is shorter than its header")
    (magic, version, codec, state, frame_id, tile_id, x, y, w, h, render_ms, readback_ms, encode_ms,
     length) = _TILE_HEADER.unpack_from(message)
    if magic != TILE_MAGIC:
        raise ProtocolError(f"bad tile magic {magic!r}")
    if version != PROTOCOL_VERSION:
        raise ProtocolError(f"tile protocol version {version}, expected {PROTOCOL_VERSION}")
    try:
        codec_value = Codec(codec & ~DEPTH_TILE)
    except ValueError:
        raise ProtocolError(f"unknown tile codec {codec}") from None
    if length != len(message) - _TILE_HEADER.size:
        raise ProtocolError(f"tile payload length {length} != {len(message) - _TILE_HEADER.size} bytes received")
    times = (render_ms, readback_ms, encode_ms)
    if not all(math.isfinite(t) and t >= 0.0 for t in times):
        raise ProtocolError(f"tile timings must be finite and >= 0, got {times}")
    if w == 0 or h == 0:
        raise ProtocolError("tile has zero size")
    header = TileHeader(frame_id, tile_id, Rect(x, y, w, h), codec_value, render_ms, readback_ms, encode_ms, state,
                        bool(codec & DEPTH_TILE))
    return header, memoryview(message)[_TILE_HEADER.size:]


@dataclass(frozen=True, slots=True)
class FrameTileEntry:
    """One tile of a published frame: where it goes, how it is encoded, which node (slot) drew it."""

    rect: Rect
    codec: Codec
    node: int
    length: int


@dataclass(frozen=True, slots=True)
class ViewerFrame:
    """A parsed ``TFRM`` message."""

    frame_id: int
    size: tuple[int, int]
    still: bool
    input_seq: int
    tiles: list[tuple[FrameTileEntry, bytes]]
    samples: int = 0


def pack_frame(frame_id: int, size: tuple[int, int], tiles: Iterable[tuple[Rect, Codec, int, bytes]], *,
               still: bool = False, input_seq: int = 0, samples: int = 0) -> bytes:
    """Viewer frame message: header, tile table, then the tiles' encoded images (no re-encoding).
    ``tiles``: (rect, codec, node slot, payload); ``samples``: a progressive still's samples (0: none)."""
    if not 0 <= samples <= FRAME_SAMPLES_MAX:
        raise ValueError(f"samples must be 0..{FRAME_SAMPLES_MAX}, got {samples}")
    tiles = list(tiles)
    flags = (FRAME_STILL if still else 0) | samples << FRAME_SAMPLES_SHIFT
    parts = [_FRAME_HEADER.pack(FRAME_MAGIC, PROTOCOL_VERSION, flags, len(tiles), frame_id,
                                size[0], size[1], input_seq)]
    for rect, codec, node, payload in tiles:
        parts.append(_FRAME_TILE.pack(rect.x, rect.y, rect.w, rect.h, int(codec), 0, node, len(payload)))
    parts.extend(payload for _, _, _, payload in tiles)
    return b"".join(parts)


def with_input_seq(message: bytes, input_seq: int) -> bytes:
    """A copy of a packed frame message answering viewer input ``input_seq`` (one viewer's copy)."""
    if message[_INPUT_SEQ_OFFSET:_INPUT_SEQ_OFFSET + 4] == struct.pack("<I", input_seq):
        return message
    copy = bytearray(message)
    struct.pack_into("<I", copy, _INPUT_SEQ_OFFSET, input_seq)
    return bytes(copy)


def unpack_frame(message: bytes) -> ViewerFrame:
    """Parse a viewer frame message; raises ProtocolError on anything malformed."""
    if len(message) < _FRAME_HEADER.size:
        raise ProtocolError("frame message shorter than its header")
    magic, version, flags, count, frame_id, width, height, input_seq = _FRAME_HEADER.unpack_from(message)
    if magic != FRAME_MAGIC or version != PROTOCOL_VERSION:
        raise ProtocolError(f"bad frame magic/version {magic!r}/{version}")
    offset = _FRAME_HEADER.size
    entries = []
    for _ in range(count):
        if offset + _FRAME_TILE.size > len(message):
            raise ProtocolError("frame message ends inside its tile table")
        x, y, w, h, codec, _, node, length = _FRAME_TILE.unpack_from(message, offset)
        try:
            codec_value = Codec(codec)
        except ValueError:
            raise ProtocolError(f"unknown tile codec {codec}") from None
        entries.append(FrameTileEntry(Rect(x, y, w, h), codec_value, node, length))
        offset += _FRAME_TILE.size
    out = []
    for entry in entries:
        out.append((entry, bytes(message[offset:offset + entry.length])))
        offset += entry.length
    if offset != len(message):
        raise ProtocolError("frame message length does not match its tile table")
    return ViewerFrame(frame_id, (width, height), bool(flags & FRAME_STILL), input_seq, out,
                       flags >> FRAME_SAMPLES_SHIFT)
