"""The viewer's JavaScript mirrors of the shared vocabulary, read as text and compared with the
Python values they mirror: ``web/protocol.js`` against ``tessera.wire.protocol`` and ``tessera.wire.codec``,
``PHASES`` in ``web/panel.js`` against ``tessera.wire.protocol.NODE_PHASES``. (The JS tests in tests/js/
check the viewer's behaviour with those values; this is where the two sides are tied.)"""

from __future__ import annotations

import json
import re
from pathlib import Path

from tessera.geometry import Rect
from tessera.wire.codec import Codec
from tessera.wire.protocol import FRAME_MAGIC, FRAME_STILL, NO_NODE_SLOT, NODE_PHASES, PROTOCOL_VERSION, pack_frame

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
