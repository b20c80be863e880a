"""The TFRM viewer frame pinned as one golden byte string, shared with tests/js/protocol.test.mjs."""

from __future__ import annotations

import re
from pathlib import Path

from tessera.codec import Codec
from tessera.geometry import Rect
from tessera.protocol import pack_frame, unpack_frame

# The same hex string is parsed by web/protocol.js in tests/js/protocol.test.mjs.
GOLDEN = (
    "5446524d0100020004030201040000000200000000000000000000000200000002000000000000000c000000"
    "0200000000000000020000000200000001010000040000000a0b0c0d0e0f101112131415ffd8ffd9"
)
RAW_PIXELS = bytes(range(10, 22))
JPEG_MARKERS = b"\xff\xd8\xff\xd9"
TILES = [
    (Rect(0, 0, 2, 2), Codec.RAW, 0, RAW_PIXELS),
    (Rect(2, 0, 2, 2), Codec.JPEG, 1, JPEG_MARKERS),
]


def test_pack_frame_gives_the_golden_bytes():
    assert pack_frame(0x01020304, (4, 2), TILES) == bytes.fromhex(GOLDEN)


def test_unpack_frame_reads_the_golden_bytes():
    frame_id, size, tiles = unpack_frame(bytes.fromhex(GOLDEN))
    assert frame_id == 0x01020304
    assert size == (4, 2)
    assert [(e.rect, e.codec, e.node_index, e.length, payload) for e, payload in tiles] == [
        (rect, codec, node, len(payload), payload) for rect, codec, node, payload in TILES
    ]


def test_js_test_holds_the_same_golden_string():
    js = (Path(__file__).parent / "js" / "protocol.test.mjs").read_text()
    statement = re.search(r"const GOLDEN =(.*?);", js, re.DOTALL)
    assert statement, "tests/js/protocol.test.mjs lacks `const GOLDEN = ...;`"
    assert "".join(re.findall(r'"([0-9a-f]*)"', statement.group(1))) == GOLDEN
