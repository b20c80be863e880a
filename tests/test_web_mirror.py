"""The viewer's JavaScript mirrors of the shared vocabulary, read as text and compared with the
Python values they mirror: ``web/protocol.js`` against ``tessera.wire.protocol`` and ``tessera.wire.codec``,
``web/video_protocol.js`` against ``tessera.wire.video`` (its codec strings computed by Node.js over a
grid of sizes and rates; the golden TVID message tests/js/video.test.mjs parses is ``pack_video``'s),
``PHASES`` in ``web/panel.js`` against ``tessera.wire.protocol.NODE_PHASES``. (The JS tests in tests/js/
check the viewer's behaviour with those values; this is where the two sides are tied.)"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

from tessera.geometry import Rect
from tessera.wire.codec import Codec
from tessera.wire.protocol import FRAME_MAGIC, FRAME_STILL, NO_NODE_SLOT, NODE_PHASES, PROTOCOL_VERSION, pack_frame
from tessera.wire.video import (
    _H264_LEVELS,
    _VP9_LEVELS,
    VIDEO_HEADER_SIZE,
    VIDEO_KEYFRAME,
    VIDEO_MAGIC,
    VideoCodec,
    codec_string,
    pack_video,
    unpack_video,
)
from tests.browser_support import unavailable
from tests.conftest import seconds

WEB = Path(__file__).resolve().parents[1] / "web"


def js_const(source: str, name: str) -> str:
    """The initialiser text of ``export const NAME = …;`` in ``source``."""
    match = re.search(rf"^export const {name} = (.*?);$", source, re.MULTILINE | re.DOTALL)
    assert match, f"no `export const {name} = …;`"
    return match.group(1).strip()


def js_number(source: str, name: str) -> int:
    return int(js_const(source, name), 0)


def test_protocol_js_declares_the_python_wire_constants():
    source = (WEB / "protocol.js").read_text()
    header_size = len(pack_frame(0, (1, 1), []))
    tile_entry_size = len(pack_frame(0, (1, 1), [(Rect(0, 0, 1, 1), Codec.RAW, 0, b"")])) - header_size
    assert js_number(source, "PROTOCOL_VERSION") == PROTOCOL_VERSION
    assert json.loads(js_const(source, "FRAME_MAGIC")) == FRAME_MAGIC.decode("ascii")
    assert js_number(source, "FRAME_HEADER_SIZE") == header_size
    assert js_number(source, "FRAME_TILE_SIZE") == tile_entry_size
    assert js_number(source, "FRAME_STILL") == FRAME_STILL
    assert js_number(source, "NO_NODE_SLOT") == NO_NODE_SLOT


def test_protocol_js_codecs_are_tessera_codecs():
    codecs = re.fullmatch(r"Object\.freeze\(\{(.*)\}\)", js_const((WEB / "protocol.js").read_text(), "Codec"))
    assert codecs, "Codec in web/protocol.js is not `Object.freeze({NAME: number, …})`"
    pairs = dict(re.findall(r"(\w+)\s*:\s*(\d+)", codecs.group(1)))
    assert {name: int(value) for name, value in pairs.items()} == {codec.name: int(codec) for codec in Codec}


def test_panel_phases_are_the_node_phases():
    phases = js_const((WEB / "panel.js").read_text(), "PHASES")
    assert tuple(json.loads(phases)) == NODE_PHASES


def test_video_protocol_js_declares_the_python_wire_constants():
    source = (WEB / "video_protocol.js").read_text()
    assert json.loads(js_const(source, "VIDEO_MAGIC")) == VIDEO_MAGIC.decode("ascii")
    assert js_number(source, "VIDEO_KEYFRAME") == VIDEO_KEYFRAME
    assert js_number(source, "VIDEO_HEADER_SIZE") == VIDEO_HEADER_SIZE
    codecs = re.fullmatch(r"Object\.freeze\(\{(.*)\}\)", js_const(source, "VideoCodec"))
    assert codecs, "VideoCodec in web/video_protocol.js is not `Object.freeze({NAME: number, …})`"
    pairs = dict(re.findall(r"(\w+)\s*:\s*(\d+)", codecs.group(1)))
    assert {name: int(value) for name, value in pairs.items()} == {codec.name: int(codec) for codec in VideoCodec}
    for name, levels in (("H264_LEVELS", _H264_LEVELS), ("VP9_LEVELS", _VP9_LEVELS)):
        table = json.loads(re.sub(r",\s*\]", "]", js_const(source, name)))   # JSON but a trailing comma
        assert [tuple(level) for level in table] == list(levels), name


# Every codec's string in web/video_protocol.js for each [width, height, fps] of argv[1] (JSON), as JSON.
CODEC_STRINGS_JS = """
import { VideoCodec, codecString } from "./web/video_protocol.js";
const cases = JSON.parse(process.argv[1]);
const names = Object.keys(VideoCodec);
console.log(JSON.stringify(cases.map(([w, h, fps]) => names.map((name) => codecString(VideoCodec[name], w, h, fps)))));
"""


def test_video_protocol_js_codec_strings_are_codec_string():
    node = shutil.which("node")
    if node is None:
        unavailable("Node.js (node >= 20) is needed to compute web/video_protocol.js's codec strings")
    sides = (16, 64, 176, 320, 640, 721, 1280, 1281, 1920, 2048, 2560, 3840, 4096, 8192)
    cases = [(w, h, fps) for w in sides for h in sides[::3] for fps in (24.0, 30.0, 60.0, 144.0)]
    result = subprocess.run([node, "--input-type=module", "-e", CODEC_STRINGS_JS, json.dumps(cases)],
                            cwd=WEB.parent, capture_output=True, text=True, timeout=seconds(60), check=False)
    assert result.returncode == 0, result.stderr
    js = json.loads(result.stdout)
    python = [[codec_string(codec, (w, h), fps) for codec in VideoCodec] for w, h, fps in cases]
    mismatches = [(case, a, b) for case, a, b in zip(cases, js, python, strict=True) if a != b]
    assert not mismatches, f"JS vs Python codec strings differ: {mismatches[:5]}"
    assert len({s for row in python for s in row}) > 15, "the grid crosses many levels"


def test_the_js_golden_video_message_is_pack_video():
    js = (Path(__file__).parent / "js" / "video.test.mjs").read_text()
    statement = re.search(r"const GOLDEN =(.*?);", js, re.DOTALL)
    assert statement, "tests/js/video.test.mjs lacks `const GOLDEN = ...;`"
    golden = bytes.fromhex("".join(re.findall(r'"([0-9a-f]*)"', statement.group(1))))
    access_unit = bytes([0, 0, 0, 1, 0x67, 0x42])
    assert golden == pack_video(0x01020304, (640, 360), VideoCodec.VP9, True, access_unit, input_seq=0x0A0B0C0D)
    assert unpack_video(golden).data == access_unit
