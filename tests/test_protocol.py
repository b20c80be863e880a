"""Binary wire format: tile and frame messages (sans-I/O, no sockets).

The TFRM golden byte string shared with the JS viewer lives in tests/test_protocol_golden.py; JSON
control messages are tested in tests/test_messages.py.
"""

from __future__ import annotations

import struct
from dataclasses import fields, replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.balancers.base import TileTiming
from tessera.geometry import Rect
from tessera.wire.codec import Codec
from tessera.wire.protocol import (
    DEPTH_TILE,
    FRAME_MAGIC,
    NODE_PHASES,
    PROTOCOL_VERSION,
    TILE_MAGIC,
    ProtocolError,
    TileHeader,
    ViewerFrame,
    pack_frame,
    pack_tile,
    state_tag,
    unpack_frame,
    unpack_tile,
    with_input_seq,
)

#: The tile header layout, restated here so that a change to the wire format fails a test.
TILE_LAYOUT = struct.Struct("<4sBBHIIIIIIfffI")
FRAME_LAYOUT = struct.Struct("<4sBBHIIII")
FRAME_TILE_LAYOUT = struct.Struct("<IIIIBBHI")

u32 = st.integers(0, 2**32 - 1)
side = st.integers(1, 2**32 - 1)
milliseconds = st.floats(0.0, 1e6, width=32)


def tile_bytes(*, magic=TILE_MAGIC, version=PROTOCOL_VERSION, codec=1, frame=5, tile=2, rect=(0, 0, 4, 3),
               times=(1.0, 0.5, 0.25), length=None, payload=b"0123456789") -> bytes:
    """A tile message built field by field, so each field can be broken on its own."""
    declared = len(payload) if length is None else length
    return TILE_LAYOUT.pack(magic, version, codec, 0, frame, tile, *rect, *times, declared) + payload


# ------------------------------------------------------------------------------------- tile messages


def test_tile_header_is_48_bytes_and_little_endian():
    header = TileHeader(0x01020304, 7, Rect(1, 2, 3, 4), Codec.PNG, 1.5, 0.25, 2.0)
    message = pack_tile(header, b"xyz")
    assert TILE_LAYOUT.size == 48 and len(message) == 51
    assert message[:4] == b"TTIL" and message[8:12] == bytes([4, 3, 2, 1])
    assert message == tile_bytes(codec=2, frame=0x01020304, tile=7, rect=(1, 2, 3, 4), times=(1.5, 0.25, 2.0),
                                 payload=b"xyz")


def test_tile_header_carries_the_low_16_bits_of_the_scene_state_version():
    header = TileHeader(1, 2, Rect(0, 0, 4, 4), Codec.PNG, 1.0, 1.0, 1.0, state=state_tag(0x12345))
    message = pack_tile(header, b"x")
    assert message[6:8] == bytes([0x45, 0x23]) and unpack_tile(message)[0].state == 0x2345
    assert state_tag(None) == 0 and state_tag(0xFFFF) == 0xFFFF and state_tag(0x10000) == 0


def test_depth_tiles_set_the_codec_byte_s_high_bit():
    header = TileHeader(1, 2, Rect(0, 0, 4, 4), Codec.JPEG, 1.0, 1.0, 1.0, depth=True)
    message = pack_tile(header, b"x")
    assert message[5] == DEPTH_TILE | Codec.JPEG and unpack_tile(message)[0] == header
    assert pack_tile(replace(header, depth=False), b"x")[5] == Codec.JPEG, "sort-first tiles as before"


@settings(max_examples=100, deadline=None)
@given(frame=u32, tile=u32, x=u32, y=u32, w=side, h=side, codec=st.sampled_from(list(Codec)),
       times=st.tuples(milliseconds, milliseconds, milliseconds), payload=st.binary(max_size=300))
def test_tile_round_trip(frame, tile, x, y, w, h, codec, times, payload):
    header = TileHeader(frame, tile, Rect(x, y, w, h), codec, *times)
    parsed, body = unpack_tile(pack_tile(header, payload))
    assert parsed == header
    assert isinstance(parsed.codec, Codec)
    assert bytes(body) == payload


@pytest.mark.parametrize(("message", "fragment"), [
    pytest.param(b"", "shorter than its header", id="empty"),
    pytest.param(tile_bytes()[:47], "shorter than its header", id="47-bytes"),
    pytest.param(tile_bytes(magic=b"TFRM"), "magic", id="frame-magic"),
    pytest.param(tile_bytes(magic=b"\0\0\0\0"), "magic", id="zero-magic"),
    pytest.param(tile_bytes(version=0), "version", id="version-0"),
    pytest.param(tile_bytes(version=PROTOCOL_VERSION + 1), "version", id="version-next"),
    pytest.param(tile_bytes(codec=3), "codec", id="codec-3"),
    pytest.param(tile_bytes(codec=255), "codec", id="codec-255"),
    pytest.param(tile_bytes(length=11), "length", id="length-over"),
    pytest.param(tile_bytes(length=9), "length", id="length-under"),
    pytest.param(tile_bytes(length=0), "length", id="length-zero"),
    pytest.param(tile_bytes()[:-1], "length", id="payload-cut"),
    pytest.param(tile_bytes() + b"!", "length", id="payload-extra"),
    pytest.param(tile_bytes(times=(float("nan"), 0.0, 0.0)), "timings", id="render-nan"),
    pytest.param(tile_bytes(times=(0.0, float("inf"), 0.0)), "timings", id="readback-inf"),
    pytest.param(tile_bytes(times=(0.0, 0.0, -float("inf"))), "timings", id="encode-minus-inf"),
    pytest.param(tile_bytes(times=(0.0, -0.5, 0.0)), "timings", id="readback-negative"),
    pytest.param(tile_bytes(rect=(0, 0, 0, 3)), "zero size", id="zero-width"),
    pytest.param(tile_bytes(rect=(0, 0, 4, 0)), "zero size", id="zero-height"),
])
def test_unpack_tile_rejects_malformed_messages(message, fragment):
    with pytest.raises(ProtocolError, match=fragment):
        unpack_tile(message)


def test_unpack_tile_accepts_an_empty_payload():
    header, body = unpack_tile(tile_bytes(payload=b""))
    assert header.rect == Rect(0, 0, 4, 3) and bytes(body) == b""


# ------------------------------------------------------------------------------------ frame messages


FRAME_TILES = [
    (Rect(0, 0, 40, 30), Codec.JPEG, 0, b"\xff\xd8jpeg bytes\xff\xd9"),
    (Rect(40, 0, 24, 30), Codec.PNG, 3, b"\x89PNG..." * 5),
    (Rect(0, 30, 64, 18), Codec.RAW, 255, bytes(range(256)) * 2),
    (Rect(0, 48, 64, 1), Codec.RAW, 1, b""),
]


def test_frame_round_trip_with_several_tiles():
    message = pack_frame(123456, (64, 49), FRAME_TILES)
    assert len(message) == FRAME_LAYOUT.size + 4 * FRAME_TILE_LAYOUT.size + sum(len(t[3]) for t in FRAME_TILES)
    frame = unpack_frame(message)
    assert (frame.frame_id, frame.size, frame.still, frame.input_seq) == (123456, (64, 49), False, 0)
    assert len(frame.tiles) == len(FRAME_TILES)
    for (entry, payload), (rect, codec, node, original) in zip(frame.tiles, FRAME_TILES, strict=True):
        assert (entry.rect, entry.codec, entry.node, entry.length) == (rect, codec, node, len(original))
        assert isinstance(payload, bytes) and payload == original


def test_frame_with_no_tiles_round_trips():
    assert unpack_frame(pack_frame(0, (16, 16), [])) == ViewerFrame(0, (16, 16), False, 0, [])


def test_still_flag_and_input_number_round_trip_and_patch_per_viewer():
    message = pack_frame(7, (64, 49), FRAME_TILES, still=True, input_seq=12)
    frame = unpack_frame(message)
    assert frame.still and frame.input_seq == 12
    patched = unpack_frame(with_input_seq(message, 2**32 - 1))
    assert patched.input_seq == 2**32 - 1 and patched.still and patched.tiles == frame.tiles
    assert with_input_seq(message, 12) is message, "no copy when the number is already right"


def frame_bytes(*, magic=FRAME_MAGIC, version=PROTOCOL_VERSION, count=1, codec=1, length=3,
                payload=b"abc") -> bytes:
    header = FRAME_LAYOUT.pack(magic, version, 0, count, 9, 8, 8, 0)
    return header + FRAME_TILE_LAYOUT.pack(0, 0, 8, 8, codec, 0, 0, length) + payload


@pytest.mark.parametrize("message", [
    pytest.param(b"", id="empty"),
    pytest.param(frame_bytes()[:23], id="short-header"),
    pytest.param(frame_bytes(magic=b"TTIL"), id="bad-magic"),
    pytest.param(frame_bytes(version=1), id="old-version"),
    pytest.param(frame_bytes(payload=b"ab"), id="payload-short"),
    pytest.param(frame_bytes(payload=b"abcd"), id="trailing-byte"),
    pytest.param(frame_bytes(length=2), id="length-too-small"),
    pytest.param(frame_bytes(count=2), id="table-truncated-by-count"),
    pytest.param(frame_bytes()[:34], id="table-truncated"),
    pytest.param(frame_bytes(codec=7), id="unknown-codec"),
])
def test_unpack_frame_rejects_malformed_messages(message):
    with pytest.raises(ProtocolError):
        unpack_frame(message)


def test_node_phases_are_the_measured_timings_in_pipeline_order():
    """NODE_PHASES names the timings the wire carries: the tile header's ``*_ms`` fields in packing
    order, then ``tile_sent.send_ms`` (measured once the tile went out); the balancers' per-tile
    timing has the same fields in the same order. web/panel.js mirrors it (tests/test_web_mirror.py)."""
    header = TileHeader(1, 0, Rect(0, 0, 1, 1), Codec.RAW, 1.0, 2.0, 3.0)
    timings = [f.name for f in fields(TileHeader) if f.name.endswith("_ms")]
    assert [name.removesuffix("_ms") for name in timings] == list(NODE_PHASES[:-1])
    packed = TILE_LAYOUT.unpack(pack_tile(header, b"")[:TILE_LAYOUT.size])
    assert packed[10:13] == tuple(getattr(header, name) for name in timings), "packed in NODE_PHASES order"
    assert [f.name for f in fields(TileTiming) if f.name.endswith("_ms")] == [f"{p}_ms" for p in NODE_PHASES]
    timing = TileTiming(Rect(0, 0, 1, 1), 0, 1.0, 2.0, 3.0, 4.0)
    assert timing.phase_ms == tuple(getattr(timing, f"{p}_ms") for p in NODE_PHASES), "the roll-up's order"

