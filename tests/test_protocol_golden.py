"""The TFRM viewer frame pinned as one golden byte string, shared with tests/js/protocol.test.mjs."""

from __future__ import annotations

import re
from pathlib import Path

from tessera.geometry import Rect
from tessera.wire.codec import Codec
from tessera.wire.protocol import pack_frame, unpack_frame

# The same hex string is parsed by web/protocol.js in tests/js/protocol.test.mjs.
GOLDEN = (
    "5446524d020102000403020104000000020000000d0c0b0a00000000000000000200000002000000000000000c000000"
    "0200000000000000020000000200000001000102040000000a0b0c0d0e0f101112131415ffd8ffd9"
)
RAW_PIXELS = bytes(range(10, 22))
JPEG_MARKERS = b"\xff\xd8\xff\xd9"
TILES = [
    (Rect(0, 0, 2, 2), Codec.RAW, 0, RAW_PIXELS),
    (Rect(2, 0, 2, 2), Codec.JPEG, 0x0201, JPEG_MARKERS),
]
INPUT_SEQ = 0x0A0B0C0D


def test_pack_frame_gives_the_golden_bytes():
    assert pack_frame(0x01020304, (4, 2), TILES, still=True, input_seq=INPUT_SEQ) == bytes.fromhex(GOLDEN)


def test_unpack_frame_reads_the_golden_bytes():
    frame = unpack_frame(bytes.fromhex(GOLDEN))
    assert frame.frame_id == 0x01020304
    assert frame.size == (4, 2)
    assert frame.still and frame.input_seq == INPUT_SEQ
    assert [(e.rect, e.codec, e.node, e.length, payload) for e, payload in frame.tiles] == [
        (rect, codec, node, len(payload), payload) for rect, codec, node, payload in TILES
    ]


def test_js_test_holds_the_same_golden_string():
    js = (Path(__file__).parent / "js" / "protocol.test.mjs").read_text()
    statement = re.search(r"const GOLDEN =(.*?);", js, re.DOTALL)
    assert statement, "tests/js/protocol.test.mjs lacks `const GOLDEN = ...;`"
    assert "".join(re.findall(r'"([0-9a-f]*)"', statement.group(1))) == GOLDEN
