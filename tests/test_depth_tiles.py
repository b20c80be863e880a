"""Depth tiles without GL (issue 10): what a node sends in the hybrid and sort-last modes round-trips
bit for bit, its counts say what it carries, the coordinator refuses every malformed or misplaced
tile with a reason (never a decompression bomb), and a hybrid frame's published tiles cover the
frame: each core as sent, the rest cut from the merge."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from tessera.compositing.depth_merge import merge_by_depth, merge_depth_tiles
from tessera.compositing.layers import FAR, BlendLayer, DepthLayer, background_pixel
from tessera.decomposition.hybrid import hybrid_frame_tiles
from tessera.geometry import Rect
from tessera.wire.codec import Codec, decode
from tessera.wire.depth_tiles import encode_depth_tile, read_depth_tile
from tessera.wire.protocol import ProtocolError

SIZE = (64, 48)
FRAME = Rect(0, 0, *SIZE)
BACKGROUND = background_pixel((0.1, 0.2, 0.3))


def random_layer(rect: Rect, seed: int, empty_share: float = 0.5) -> DepthLayer:
    rng = np.random.default_rng(seed)
    depth = rng.random((rect.h, rect.w), dtype=np.float32) * np.float32(0.99)
    depth[rng.random((rect.h, rect.w)) < empty_share] = FAR
    return DepthLayer(rect, rng.integers(0, 256, (rect.h, rect.w, 3), dtype=np.uint8), depth, 0)


def test_a_sort_last_layer_round_trips_bit_for_bit():
    layer = random_layer(Rect(5, 7, 30, 20), seed=1)
    payload, counts = encode_depth_tile(layer, None, Codec.PNG, 90, version=4)
    tile = read_depth_tile(payload, FRAME, None, slot=2)
    assert tile.version == 4 and tile.core is None and len(tile.layers) == 1
    (back,) = tile.layers
    active = layer.depth < FAR
    assert back.rect == layer.rect and back.slot == 2
    assert np.array_equal(back.depth, layer.depth)
    assert np.array_equal(back.color[active], layer.color[active])
    assert counts.depth_px == counts.color_px == int(active.sum())
    assert counts.depth_bytes + counts.color_bytes + 8 + 16 == len(payload)


def test_nothing_in_view_sends_no_piece():
    payload, counts = encode_depth_tile(None, None, Codec.JPEG, 60, version=1)
    assert read_depth_tile(payload, FRAME, None, 0).layers == ()
    assert counts.as_stats() == {"color_px": 0, "color_bytes": 0, "depth_px": 0, "depth_bytes": 0}
    empty = DepthLayer(Rect(0, 0, 8, 8), np.zeros((8, 8, 3), np.uint8), np.full((8, 8), FAR, np.float32), 0)
    assert encode_depth_tile(empty, None, Codec.PNG, 90, version=1)[0] == payload, "all-far pieces are left out"


def test_a_depth_tile_s_extent_holds_its_core_and_pieces_and_is_none_when_nothing_was_drawn():
    tile, core, read = Rect(16, 0, 32, 48), Rect(20, 0, 24, 44), Rect(12, 0, 40, 48)
    hybrid, _ = encode_depth_tile(random_layer(read, seed=3, empty_share=0.0), core, Codec.PNG, 90)
    assert read_depth_tile(hybrid, read, (core, tile), slot=1).extent == read
    share = Rect(5, 7, 30, 20)
    layer = random_layer(share, seed=4, empty_share=0.0)
    assert read_depth_tile(encode_depth_tile(layer, None, Codec.PNG, 90, 1)[0], FRAME, None, 0).extent == share
    assert read_depth_tile(encode_depth_tile(None, None, Codec.PNG, 90, 1)[0], FRAME, None, 0).extent is None


def test_a_hybrid_tile_sends_its_core_as_an_image_and_its_ring_with_depth():
    tile, core = Rect(16, 0, 32, 48), Rect(20, 0, 24, 44)
    layer = random_layer(Rect(12, 0, 40, 48), seed=2, empty_share=0.2)
    payload, counts = encode_depth_tile(layer, core, Codec.PNG, 90)
    decoded = read_depth_tile(payload, Rect(12, 0, 40, 48), (core, tile), slot=1)
    assert decoded.core is not None and decoded.core[0] == core
    assert np.array_equal(decode(decoded.core[1], Codec.PNG, core.w, core.h), layer.color[0:44, 8:32])
    assert sum(piece.rect.area for piece in decoded.layers) == layer.rect.area - core.area
    assert counts.color_px == core.area + counts.depth_px
    assert counts.color_bytes > len(decoded.core[1])


def test_merged_hybrid_frames_equal_the_compositor_s_result():
    """Two tiles side by side with 8 px strips: published tiles cover the frame exactly; each core
    is forwarded as sent and the rest is the depth merge."""
    tiles = [Rect(0, 0, 32, 48), Rect(32, 0, 32, 48)]
    reads = [Rect(0, 0, 40, 48), Rect(24, 0, 40, 48)]
    cores = [Rect(0, 0, 24, 48), Rect(40, 0, 24, 48)]
    layers = [random_layer(read, seed) for seed, read in enumerate(reads)]
    decoded = [read_depth_tile(encode_depth_tile(layer, core, Codec.PNG, 90)[0], read, (core, tile), slot)
               for slot, (layer, core, read, tile) in enumerate(zip(layers, cores, reads, tiles, strict=True))]
    merged = merge_depth_tiles(decoded, SIZE, BACKGROUND)
    published = hybrid_frame_tiles(list(zip(tiles, decoded, strict=True)), merged, Codec.PNG, 90)
    frame = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    covered = np.zeros(SIZE[::-1], np.int64)
    for rect, index, data in published:
        assert index in (0, 1)
        frame[rect.y:rect.y1, rect.x:rect.x1] = decode(data, Codec.PNG, rect.w, rect.h)
        covered[rect.y:rect.y1, rect.x:rect.x1] += 1
    assert (covered == 1).all()
    pieces = [DepthLayer(piece.rect, piece.color, piece.depth, slot) for slot, tile in enumerate(decoded)
              for piece in tile.layers]
    expected = merge_by_depth(pieces, SIZE, BACKGROUND,
                              [(core, layer.color[:, core.x - layer.rect.x:core.x1 - layer.rect.x])
                               for core, layer in zip(cores, layers, strict=True)])
    assert np.array_equal(frame, expected)


def pack(version=0, pieces=(), core=None, flags=None, body=b"", blend=0) -> bytes:
    """A depth tile by hand: ``pieces`` (rect, depth length, colour length), the last ``blend`` of
    them blend pieces, ``core`` (rect, length)."""
    head = struct.pack("<IHBB", version, len(pieces), (1 if core else 0) if flags is None else flags, blend)
    if core:
        head += struct.pack("<HHHHI", *core[0].as_list(), core[1])
    for rect, depth_length, color_length in pieces:
        head += struct.pack("<HHHHII", *rect.as_list(), depth_length, color_length)
    return head + body


def good_piece(rect: Rect) -> tuple[bytes, bytes]:
    """The two deflated parts of a fully active piece."""
    runs = struct.pack("<HHIII", rect.w, rect.h, 2, 0, rect.area) + struct.pack("<II", 0, 0)
    depth = runs + np.full(rect.area, 0.5, "<f4").tobytes()
    return zlib.compress(depth), zlib.compress(bytes(3 * rect.area))


PIECE = Rect(0, 0, 4, 4)
DEPTH_PART, COLOR_PART = good_piece(PIECE)


@pytest.mark.parametrize(("payload", "fragment"), [
    pytest.param(b"\x00" * 7, "no header", id="short"),
    pytest.param(pack(flags=2), "flags", id="flags"),
    pytest.param(pack(blend=1), "blend pieces", id="blend-without-pieces"),
    pytest.param(pack(pieces=[(PIECE, 1, 1)] * 5), "at most 4", id="too-many"),
    pytest.param(pack(pieces=[(PIECE, 1, 1)])[:-4], "piece table", id="table-cut"),
    pytest.param(pack(core=(Rect(0, 0, 4, 4), 1))[:-2], "core entry", id="core-cut"),
    pytest.param(pack(pieces=[(Rect(60, 0, 8, 8), 1, 1)]), "outside", id="outside"),
    pytest.param(pack(pieces=[(Rect(0, 0, 0, 8), 1, 1)]), "outside", id="empty-piece"),
    pytest.param(pack(pieces=[(PIECE, 1, 1), (Rect(2, 2, 4, 4), 1, 1)]), "overlaps", id="overlap"),
    pytest.param(pack(pieces=[(PIECE, len(DEPTH_PART), len(COLOR_PART))], body=DEPTH_PART + COLOR_PART + b"!"),
                 "tables say", id="trailing"),
    pytest.param(pack(pieces=[(PIECE, 3, len(COLOR_PART))], body=b"abc" + COLOR_PART), "inflate", id="not-zlib"),
    pytest.param(pack(pieces=[(PIECE, len(DEPTH_PART), len(zlib.compress(bytes(10**6))))],
                      body=DEPTH_PART + zlib.compress(bytes(10**6))), "more than 48 bytes", id="bomb"),
    pytest.param(pack(pieces=[(Rect(0, 0, 4, 2), len(DEPTH_PART), len(COLOR_PART))], body=DEPTH_PART + COLOR_PART),
                 "more than", id="wrong-size"),
    pytest.param(pack(core=(Rect(0, 0, 4, 4), 0)), "core", id="core-in-sort-last"),
])
def test_malformed_depth_tiles_are_refused_with_a_reason(payload, fragment):
    with pytest.raises(ProtocolError, match=fragment):
        read_depth_tile(payload, FRAME, None, 0)


def test_a_hybrid_core_must_hold_the_exclusive_part_and_stay_in_its_tile():
    tile, exclusive = Rect(0, 0, 32, 48), Rect(0, 0, 24, 48)
    for core, ok in ((exclusive, True), (tile, True), (Rect(0, 0, 20, 48), False), (Rect(0, 0, 40, 48), False)):
        payload = pack(core=(core, 0))
        if ok:
            assert read_depth_tile(payload, Rect(0, 0, 40, 48), (exclusive, tile), 0).core == (core, b"")
        else:
            with pytest.raises(ProtocolError, match="core"):
                read_depth_tile(payload, Rect(0, 0, 40, 48), (exclusive, tile), 0)
    with pytest.raises(ProtocolError, match="no core"):
        read_depth_tile(pack(), Rect(0, 0, 40, 48), (exclusive, tile), 0)
    assert read_depth_tile(pack(), Rect(0, 0, 40, 48), (None, tile), 0).core is None, "too narrow for a core"


def test_blend_pieces_round_trip_and_lay_the_fragments_in_front_over_the_merge():
    """Sort-last blended fragments peeled into two layers (depths 0.25 and 0.75): the compositor lays
    over each pixel the accumulation of the fragments in front of the merged surface (0.5): the
    first layer's, both where the opaque surface is farther, none where it is nearer."""
    rect = Rect(0, 0, 8, 4)
    opaque_depth = np.full((4, 8), 0.5, np.float32)
    opaque_depth[:, 6:] = 0.1                       # an opaque surface in front of every fragment
    opaque_depth[:, 4:6] = 0.9                      # one behind both
    opaque = DepthLayer(rect, np.full((4, 8, 3), 200, np.uint8), opaque_depth, 0)
    depth = np.stack([np.full((4, 8), 0.25, np.float32), np.full((4, 8), 0.75, np.float32)])
    depth[1, :, :2] = FAR                           # one fragment only on the left
    color = np.stack([np.full((4, 8, 3), 40, np.uint8), np.full((4, 8, 3), 70, np.uint8)])
    alpha = np.stack([np.full((4, 8), 128, np.uint8), np.full((4, 8), 192, np.uint8)])
    blend = BlendLayer(rect, color, alpha, depth, 0)
    payload, counts = encode_depth_tile(opaque, None, Codec.PNG, 90, version=2, blend=blend)
    tile = read_depth_tile(payload, FRAME, None, slot=1)
    assert len(tile.layers) == 1 and len(tile.blends) == 1 and counts.depth_px == 32 + 32 + 24
    (back,) = tile.blends
    assert back.slot == 1 and np.array_equal(back.depth, depth)
    assert np.array_equal(back.alpha[depth < FAR], alpha[depth < FAR])
    frame = merge_depth_tiles([tile], SIZE, BACKGROUND)
    assert (frame[0, :4] == 40 + round(127 / 255 * 200)).all(), "the nearer fragment alone"
    assert (frame[0, 4:6] == 70 + round(63 / 255 * 200)).all(), "both fragments"
    assert (frame[0, 6:8] == 200).all(), "behind the opaque surface: unchanged"
    assert (frame[10, 10] == BACKGROUND).all()
    with pytest.raises(ProtocolError, match=r"active pixels|alpha values"):
        _cut_alpha(payload)


def _cut_alpha(payload: bytes) -> None:
    """A blend piece whose colour part lacks one alpha value."""
    version, count, flags, blend = struct.unpack_from("<IHBB", payload)
    entries = [struct.unpack_from("<HHHHII", payload, 8 + 16 * i) for i in range(count)]
    body = 8 + 16 * count
    parts, offset = [], body
    for *_, depth_length, color_length in entries:
        parts.append((payload[offset:offset + depth_length], payload[offset + depth_length:offset + depth_length
                                                                      + color_length]))
        offset += depth_length + color_length
    colour = zlib.decompress(parts[-1][1])[:-1]
    parts[-1] = (parts[-1][0], zlib.compress(colour))
    rebuilt = pack(version, [(Rect(*entry[:4]), len(d), len(c)) for entry, (d, c) in zip(entries, parts, strict=True)],
                   flags=flags, body=b"".join(d + c for d, c in parts), blend=blend)
    read_depth_tile(rebuilt, FRAME, None, 0)
