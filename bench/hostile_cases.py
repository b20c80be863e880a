"""Hostile input for the coordinator, from a seeded generator: what ``bench.hostile`` and
``tests/test_fuzz.py`` send. Pure (no sockets, no clocks): a :class:`random.Random` in, messages out,
so a seed replays a run exactly.

Every case is bad for sure. Where a generated message might by chance be valid, the message
catalogue (:func:`tessera.wire.messages.parse`) or the camera parser is asked, and a valid one is made
again; the coordinator's answers are what the driver checks, never these oracles.

* :meth:`HostileCases.node_first` — the first message on ``/ws/node``: anything but a valid hello
  (or a hello with a wrong token); the answer must be a close with code 1008 or 4401 and a reason.
* :meth:`HostileCases.node_after_hello` — after a valid hello: malformed JSON, wrong types, wrong
  kinds, huge numbers, and binary tiles that are truncated, oversized, of unknown codecs, with
  corrupt or wrong-size PNG/JPEG payloads, decompression bombs, or for frames and tiles never
  assigned to this node; each must close the socket with a reason.
* :meth:`HostileCases.node_owed` — a node that loaded the scene answers a real ``render`` wrongly:
  wrong rect, codec or tile id, corrupt, wrong-size or foreign-format payloads, or a correct tile
  (cropped from the reference image) followed by a garbage duplicate.
* :meth:`HostileCases.viewer` — ``/ws/view`` input; each must be answered by an ``error`` message.
* :meth:`HostileCases.rest` — requests to the REST API; each must get a 4xx.
"""

from __future__ import annotations

import json
import random
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tessera.geometry import Rect
from tessera.wire.codec import Codec, encode
from tessera.wire.messages import FROM_NODE, FROM_VIEWER, NodeHello, parse
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError, TileHeader, pack_tile

#: Byte offsets in a packed tile header (tessera.wire.protocol's "<4sBBHIIIIIIfffI").
_MAGIC, _VERSION, _CODEC, _FRAME, _TILE, _RECT, _TIMES, _LENGTH = 0, 4, 5, 8, 12, 16, 32, 44
#: Control messages over the coordinator's 1 MiB limit are this long.
OVERSIZE_BYTES = (1 << 20) + 4096
#: A sentinel the driver sends after a node's bad message: if the close names it, the bad
#: message went unanswered.
SENTINEL = "sentinel: not JSON"
#: Side of the decompression bomb's PNG (px).
BOMB_SIDE = 9000


@dataclass(frozen=True)
class Bad:
    """One hostile message: ``label`` (its family, for the figures) and what goes on the wire."""

    label: str
    data: str | bytes


@dataclass(frozen=True)
class Request:
    """One hostile REST request."""

    label: str
    method: str
    path: str
    params: dict[str, str] = field(default_factory=dict)
    headers: dict[str, str] = field(default_factory=dict)
    content: bytes | None = None


@dataclass(frozen=True)
class Frames:
    """What the driver knows of the coordinator's frames: the newest published id (0: none yet)."""

    last: int


def _wrong_values(rng: random.Random) -> Any:
    return rng.choice([
        None, True, False, "", "x" * rng.randint(1, 300), -1, 0, 2**31, 2**64, 10**30, -10**30, 1e308, -1e308,
        0.5, -0.0, [], {}, [1, 2, 3], {"a": 1}, "NaN", [[[[]]]], "\u202e\u0000\ud7ff",
    ])


def _huge_int_text(rng: random.Random) -> str:
    return "1" + "0" * rng.choice([20, 300, 4299, 5000])


class HostileCases:
    """The seeded generator; ``token``: the coordinator's, so that the right one can be left out."""

    def __init__(self, seed: int, token: str | None = None) -> None:
        self.rng = random.Random(seed)
        self.token = token or ""
        self._bomb: bytes | None = None

    # ----------------------------------------------------------------------------------- text
    def junk_text(self) -> tuple[str, str]:
        """(label, text) that is no JSON object at all."""
        rng = self.rng
        kind = rng.choices(["garbage", "truncated", "empty", "scalar", "array", "nested", "huge-int", "nan",
                            "oversize", "unicode"], weights=[10, 10, 5, 5, 5, 5, 5, 5, 1, 5])[0]
        if kind == "garbage":
            return kind, "".join(chr(rng.randint(33, 126)) for _ in range(rng.randint(1, 200)))
        if kind == "truncated":
            text = json.dumps({"type": "hello", "name": "x", "version": PROTOCOL_VERSION})
            return kind, text[:rng.randint(1, len(text) - 1)]
        if kind == "empty":
            return kind, rng.choice(["", " ", "\n\t"])
        if kind == "scalar":
            return kind, rng.choice(["null", "true", "0", "-1e400", "\"hello\"", "1e999"])
        if kind == "array":
            return kind, json.dumps([{"type": "hello"}] * rng.randint(0, 3))
        if kind == "nested":
            depth = rng.choice([100, 5000, 200_000])
            return kind, "[" * depth + "]" * depth
        if kind == "huge-int":
            return kind, '{"type": "tile_sent", "frame": ' + _huge_int_text(rng) + "}"
        if kind == "nan":
            return kind, '{"type": "camera", "camera": {"eye": [NaN, 0, Infinity], "target": [0, 0, 0]}}'
        if kind == "oversize":
            return kind, json.dumps({"type": "scene_progress", "message": "x" * OVERSIZE_BYTES})
        return kind, "\u00ff\u2603\U0001f600" * rng.randint(1, 50)

    def junk(self, prefix: str) -> Bad:
        """:meth:`junk_text` as a bad message labelled ``PREFIX.KIND``."""
        kind, text = self.junk_text()
        return Bad(f"{prefix}.{kind}", text)

    def _mutated(self, template: dict[str, Any]) -> dict[str, Any]:
        """``template`` with one field given a wrong value, removed, or nested wrongly."""
        rng = self.rng
        message = json.loads(json.dumps(template))
        key = rng.choice([k for k in message if k != "type"] or ["type"])
        action = rng.random()
        if action < 0.15:
            message.pop(key, None)
        elif action < 0.25:
            message["type"] = _wrong_values(rng)
        else:
            message[key] = _wrong_values(rng)
        return message

    # ----------------------------------------------------------------------------------- nodes
    def hello(self, **fields: Any) -> dict[str, Any]:
        return {"type": "hello", "name": "hostile", "token": self.token, "renderer": "none",
                "version": PROTOCOL_VERSION, "capabilities": {"slowdown": 1.0, "calibrate": False}, **fields}

    def node_first(self) -> Bad:
        """A first message on ``/ws/node`` that is not a valid hello."""
        rng = self.rng
        while True:
            roll = rng.random()
            if roll < 0.3:
                return self.junk("node.first")
            if roll < 0.4:
                return Bad("node.first.binary", self._some_tile(frame=1) if rng.random() < 0.5
                           else rng.randbytes(rng.randint(0, 64)))
            if roll < 0.5 and self.token:
                wrong = rng.choice(["", "x", self.token + "x"])
                return Bad("node.first.wrong-token", json.dumps(self.hello(token=wrong)))
            if roll < 0.6:
                version = rng.choice([0, 1, PROTOCOL_VERSION + 1, -1, 2**64, 10**30, str(PROTOCOL_VERSION),
                                      float(PROTOCOL_VERSION) + 0.5, None, True])
                text = json.dumps(self.hello(version=version))
                label = "node.first.version"
            elif roll < 0.8:
                text = json.dumps(self._mutated(self.hello()))
                label = "node.first.hello-field"
            else:
                text = json.dumps(self._mutated(rng.choice(list(self._node_templates(1).values()))))
                label = "node.first.not-hello"
            if not self._parses(text, [NodeHello]):
                return Bad(label, text)

    def node_after_hello(self, frames: Frames) -> Bad:
        """A bad message from a node that said hello (and loaded no scene)."""
        rng = self.rng
        while True:
            roll = rng.random()
            if roll < 0.15:
                return self.junk("node.text")
            if roll < 0.5:
                return self._bad_tile(frames)
            templates = self._node_templates(max(frames.last, 1))
            name = rng.choice(list(templates))
            if roll < 0.6:
                # well-formed, about tiles this node never owed, or answers it was never asked for
                if name in ("tile_sent", "render_error", "tiles_dropped", "calibration"):
                    return Bad(f"node.unasked.{name}", json.dumps(templates[name]))
                continue
            text = json.dumps(self._mutated(templates[name]))
            if not self._parses(text, FROM_NODE):
                return Bad(f"node.field.{name}", text)

    @staticmethod
    def _node_templates(frame: int) -> dict[str, dict[str, Any]]:
        return {
            "scene_progress": {"type": "scene_progress", "scene": "s", "fraction": 0.5, "message": "m"},
            "scene_ready": {"type": "scene_ready", "triangles": 1, "bounds": [[0, 0, 0], [1, 1, 1]],
                            "groups": {"boxes": [[0, 0, 0, 1, 1, 1]], "counts": [1]}},
            "scene_error": {"type": "scene_error", "scene": "s", "message": "m"},
            "tile_sent": {"type": "tile_sent", "frame": frame, "tile": 0, "send_ms": 1.0, "stats": {"triangles": 1}},
            "render_error": {"type": "render_error", "frame": frame, "tile": 0, "message": "m"},
            "tiles_dropped": {"type": "tiles_dropped", "frame": frame, "tiles": [0, 1]},
            "calibration": {"type": "calibration", "ms": 1.0},
        }

    @staticmethod
    def _parses(text: str, kinds: Any) -> bool:
        try:
            parse(text, kinds)
        except ProtocolError:
            return False
        return True

    # ----------------------------------------------------------------------------------- tiles
    def _png(self, w: int, h: int, value: int | None = None) -> bytes:
        fill = self.rng.randint(0, 255) if value is None else value
        return encode(np.full((h, w, 3), fill, dtype=np.uint8), Codec.PNG)

    def _some_tile(self, frame: int, tile: int = 0, rect: Rect | None = None, codec: Codec = Codec.PNG,
                   payload: bytes | None = None) -> bytes:
        rect = rect or Rect(0, 0, 8, 8)
        if payload is None:
            payload = self._png(rect.w, rect.h)
        return pack_tile(TileHeader(frame, tile, rect, codec, 1.0, 1.0, 1.0), payload)

    def corrupt_png(self, w: int, h: int) -> bytes:
        """A PNG of ``w`` × ``h`` that cannot be decoded: its signature or header broken, its image
        data cut short, or its zlib stream's header or body overwritten (a flip in a chunk's CRC
        alone would not do: decoders skip those, and the pixels would be wrong but readable)."""
        rng = self.rng
        payload = bytearray(self._png(w, h))
        data = payload.index(b"IDAT") + 4
        kind = rng.choice(["signature", "header", "cut", "zlib", "body"])
        if kind == "signature":
            payload[rng.randint(0, 7)] ^= 0xFF
        elif kind == "header":
            payload[16:24] = rng.randbytes(8)
        elif kind == "cut":
            return bytes(payload[:rng.randint(data, data + 2)])
        elif kind == "zlib":
            payload[data:data + 2] = b"\x00\x00"
        else:
            end = data + int.from_bytes(payload[data - 8:data - 4], "big")
            payload[data + 2:end] = bytes(b ^ 0x5A for b in payload[data + 2:end])
        return bytes(payload)

    def bomb(self) -> bytes:
        """A valid black PNG of :data:`BOMB_SIDE`² pixels in about 240 KB: 243 MB once decoded (under
        Pillow's own decompression-bomb limit, so only the coordinator's checks stand in its way)."""
        if self._bomb is None:
            def chunk(kind: bytes, data: bytes) -> bytes:
                return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
            header = struct.pack(">IIBBBBB", BOMB_SIDE, BOMB_SIDE, 8, 2, 0, 0, 0)
            squeeze = zlib.compressobj(9)
            row = b"\x00" * (1 + 3 * BOMB_SIDE)
            rows = b"".join(squeeze.compress(row) for _ in range(BOMB_SIDE)) + squeeze.flush()
            self._bomb = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")
        return self._bomb

    def _bad_tile(self, frames: Frames) -> Bad:
        """A binary tile from a node owed nothing: malformed, or well-formed for frames and tiles it
        was never given."""
        rng = self.rng
        last = max(frames.last, 1)
        kind = rng.choice(["short", "magic", "version", "codec", "truncated", "oversized", "timing", "zero-size",
                           "frame-zero", "frame-future", "frame-max", "frame-past", "frame-past", "corrupt-png",
                           "jpeg-for-png", "wrong-size-png", "bomb", "huge-rect", "random"])
        tile = bytearray(self._some_tile(frame=rng.randint(1, last)))
        if kind == "short":
            return Bad("node.tile.short", bytes(tile[:rng.randint(0, 47)]))
        if kind == "magic":
            tile[_MAGIC:_MAGIC + 4] = rng.choice([b"TFRM", b"ttil", b"\x00\x00\x00\x00", rng.randbytes(4)])
        elif kind == "version":
            tile[_VERSION] = rng.choice([0, 1, PROTOCOL_VERSION + 1, 255])
        elif kind == "codec":
            tile[_CODEC] = rng.randint(3, 255)
        elif kind == "truncated":
            tile = tile[:rng.randint(49, len(tile) - 1)]
        elif kind == "oversized":
            tile += rng.randbytes(rng.choice([1, 1000, 1 << 20]))
        elif kind == "timing":
            struct.pack_into("<f", tile, _TIMES + 4 * rng.randint(0, 2), rng.choice([float("nan"), float("inf"), -1.0]))
        elif kind == "zero-size":
            struct.pack_into("<II", tile, _RECT + 8, rng.choice([0, 8]), 0)
        elif kind == "frame-zero":
            struct.pack_into("<I", tile, _FRAME, 0)
        elif kind == "frame-future":
            struct.pack_into("<I", tile, _FRAME, last + rng.randint(1000, 10**6))
        elif kind == "frame-max":
            struct.pack_into("<I", tile, _FRAME, 2**32 - 1)
        elif kind == "frame-past":
            struct.pack_into("<II", tile, _FRAME, rng.randint(1, last), rng.randint(0, 3))
        elif kind == "corrupt-png":
            tile = bytearray(self._some_tile(1, payload=self.corrupt_png(8, 8)))
        elif kind == "jpeg-for-png":
            jpeg = encode(np.zeros((8, 8, 3), dtype=np.uint8), Codec.JPEG)
            tile = bytearray(self._some_tile(1, payload=jpeg))
        elif kind == "wrong-size-png":
            tile = bytearray(self._some_tile(1, payload=self._png(9, 7)))
        elif kind == "bomb":
            tile = bytearray(self._some_tile(1, rect=Rect(0, 0, BOMB_SIDE, BOMB_SIDE), payload=self.bomb()))
        elif kind == "huge-rect":
            struct.pack_into("<IIII", tile, _RECT, 2**32 - 8, 2**32 - 8, 8, 8)
        else:
            tile = bytearray(b"TTIL" + rng.randbytes(rng.randint(44, 300)))
        return Bad(f"node.tile.{kind}", bytes(tile))

    def node_owed(self, render: dict[str, Any], reference: Callable[[dict[str, Any], Rect], np.ndarray | None]
                  ) -> list[Bad]:
        """What a node that loaded the scene sends back for a real ``render`` message: one bad
        answer, or a correct tile (``reference(camera, rect)``, when it knows the camera) followed
        by a garbage duplicate. The coordinator must close it at the bad tile."""
        rng = self.rng
        frame, tiles = render["frame"], render["tiles"]
        entry = rng.choice(tiles)
        tile_id, rect = entry["tile"], Rect(*entry["rect"])
        codec = Codec.parse(render["codec"])
        kind = rng.choice(["rect", "codec", "tile-id", "corrupt", "wrong-size", "jpeg", "raw-size", "duplicate",
                           "duplicate", "other-frame"])
        if kind == "duplicate":
            pixels = reference(render["camera"], rect)
            if pixels is not None:
                good = self._some_tile(frame, tile_id, rect, codec, encode(np.ascontiguousarray(pixels), codec))
                sent = json.dumps({"type": "tile_sent", "frame": frame, "tile": tile_id, "send_ms": 0.1})
                garbage = self._some_tile(frame, tile_id, rect, codec, self._png(rect.w, rect.h, 255))
                return [Bad("node.owed.good", good), Bad("node.owed.good-sent", sent),
                        Bad("node.owed.duplicate", garbage)]
            kind = "rect"
        if kind == "rect":
            shifted = Rect(rect.x + 1, rect.y, max(rect.w - 1, 1), rect.h) if rng.random() < 0.5 else \
                Rect(rect.x, rect.y, rect.w, rect.h + 1)
            data = self._some_tile(frame, tile_id, shifted, codec, self._png(shifted.w, shifted.h))
        elif kind == "codec":
            other = rng.choice([c for c in Codec if c is not codec])
            pixels = np.zeros((rect.h, rect.w, 3), dtype=np.uint8)
            data = self._some_tile(frame, tile_id, rect, other, encode(pixels, other))
        elif kind == "tile-id":
            data = self._some_tile(frame, rng.choice([len(tiles) + 5, 2**32 - 1]), rect, codec,
                                   self._png(rect.w, rect.h))
        elif kind == "corrupt":
            data = self._some_tile(frame, tile_id, rect, codec, self.corrupt_png(rect.w, rect.h))
        elif kind == "wrong-size":
            data = self._some_tile(frame, tile_id, rect, codec, self._png(rect.w + 1, rect.h))
        elif kind == "jpeg":
            data = self._some_tile(frame, tile_id, rect, codec,
                                   encode(np.zeros((rect.h, rect.w, 3), dtype=np.uint8), Codec.JPEG))
        elif kind == "raw-size":
            data = self._some_tile(frame, tile_id, rect, Codec.RAW, b"\x00" * (rect.w * rect.h * 3 - 1))
        else:  # the frame before the first this node was sent, or one never dispatched
            other = frame - 1 if frame > 1 and rng.random() < 0.5 else 2**32 - 2
            data = self._some_tile(other, tile_id, rect, codec, self._png(rect.w, rect.h))
        return [Bad(f"node.owed.{kind}", data)]

    # ----------------------------------------------------------------------------------- viewers
    def viewer(self) -> Bad:
        """Viewer input that must be refused with an ``error`` message."""
        rng = self.rng
        camera = {"eye": [0.0, 1.0, 5.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fovy_deg": 45.0}
        while True:
            roll = rng.random()
            if roll < 0.2:
                kind, text = self.junk_text()
                if kind != "oversize" or rng.random() < 0.05:
                    return Bad(f"viewer.text.{kind}", text)
                continue
            if roll < 0.25:
                return Bad("viewer.binary", rng.randbytes(rng.randint(1, 256)))
            if roll < 0.55:
                bad_camera = self._bad_camera(camera)
                message = {"type": "camera", "camera": bad_camera, "seq": rng.randint(0, 100)}
                label = "viewer.camera"
            elif roll < 0.7:
                message = {"type": "camera", "camera": camera, "seq": rng.choice([-1, 2**32, 10**30, "1", 1.5])}
                label = "viewer.seq"
            elif roll < 0.85:
                message = self._mutated({"type": "latency", "p50_ms": 1.0, "p90_ms": 2.0, "samples": 3.0,
                                         "interval_ms": 16.0})
                label = "viewer.latency"
            else:
                message = self._mutated({"type": rng.choice(["hello", "render", "welcome", "frame", "camera"]),
                                         "camera": camera})
                label = "viewer.kind"
            text = json.dumps(message)
            if not self._parses(text, FROM_VIEWER):
                return Bad(label, text)

    def _bad_camera(self, camera: dict[str, Any]) -> Any:
        rng = self.rng
        kind = rng.choice(["field", "degenerate", "up", "fovy", "near-far", "length", "extra", "type"])
        bad = dict(camera)
        if kind == "field":  # a value no field takes, or a required field left out
            key = rng.choice(["eye", "target", "up", "fovy_deg"])
            if key in ("eye", "target") and rng.random() < 0.3:
                del bad[key]
            else:
                bad[key] = rng.choice([None, {}, [[[[]]]], "x" * rng.randint(1, 300), "\u202e", [1.0, 2.0]])
        elif kind == "degenerate":
            bad["target"] = list(bad["eye"])
        elif kind == "up":
            bad["up"] = rng.choice([[0.0, 0.0, 0.0], [0.0, -1.0, -5.0]])
        elif kind == "fovy":
            bad["fovy_deg"] = rng.choice([0.0, -10.0, 180.0, 1e9])
        elif kind == "near-far":
            bad["near"], bad["far"] = 10.0, 1.0
        elif kind == "length":
            bad["eye"] = [1.0] * rng.choice([0, 2, 4, 10_000])
        elif kind == "extra":
            bad["zoom"] = 2
        else:
            bad = rng.choice([None, [], "camera", 42])
        return bad

    def camera_body(self) -> tuple[str, bytes]:
        """(label, body) of a ``PUT /api/camera`` that must get a 422 (or 400)."""
        rng = self.rng
        camera = {"eye": [0.0, 1.0, 5.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fovy_deg": 45.0}
        while True:
            if rng.random() < 0.25:
                kind, text = self.junk_text()
                if kind == "oversize" and rng.random() > 0.05:
                    continue
                return f"camera.text.{kind}", text.encode("utf-8", "surrogatepass")
            return "camera.body", json.dumps(self._bad_camera(camera)).encode()

    # ----------------------------------------------------------------------------------- REST
    def rest(self) -> Request:
        rng = self.rng
        json_type = {"content-type": "application/json"}
        roll = rng.random()
        if roll < 0.3:
            label, body = self.camera_body()
            return Request(label, "PUT", "/api/camera", headers=json_type, content=body)
        if roll < 0.5:
            return self._balancer_request()
        if roll < 0.65:
            params = rng.choice([
                {"after": "-1"}, {"after": "abc"}, {"after": "1e3"}, {"after": _huge_int_text(rng)},
                {"after": str(10**30)}, {"after": str(2**63)}, {"timeout": "0"}, {"timeout": "-1"},
                {"timeout": "nan"}, {"timeout": "inf"}, {"timeout": "301"}, {"still": "maybe"},
                {"after": "", "timeout": ""}])
            return Request("frame.query", "GET", "/api/frame.png", params=params)
        if roll < 0.75:
            method, path = rng.choice([("POST", "/api/camera"), ("DELETE", "/api/balancer"), ("PUT", "/api/stats"),
                                       ("GET", "/api/nodes/calibrate"), ("POST", "/healthz"), ("PATCH", "/api/camera")])
            return Request("method", method, path)
        if roll < 0.85:
            path = rng.choice(["/api/nope", "/api/camera/extra", "/web/../server/app.py", "/web/%2e%2e/README.md",
                               "/api/" + "x" * rng.choice([10, 4000]), "/ws/node", "/ws/view", "/%00",
                               "/web/does-not-exist.js"])
            return Request("path", "GET", path)
        if roll < 0.95:
            content_type = rng.choice(["text/plain", "application/x-www-form-urlencoded", "multipart/form-data",
                                       "application/json; charset=latin-1"])
            body = rng.choice([b"eye=1&target=2", b"\xff\xfe\x00", b'{"eye": [0, 1, 5]}', b""])
            return Request("content-type", "PUT", rng.choice(["/api/camera", "/api/balancer"]),
                           headers={"content-type": content_type}, content=body)
        if self.token:
            headers = rng.choice([{}, {"authorization": "Bearer wrong"}, {"x-tessera-token": ""},
                                  {"cookie": "tessera_token=wrong"}, {"authorization": "Basic x"}])
            return Request("token", rng.choice(["GET", "PUT"]), rng.choice(["/api/stats", "/api/camera"]),
                           headers={"x-no-auth": "1", **headers})
        return Request("path", "GET", "/api/none")

    def _balancer_request(self) -> Request:
        rng = self.rng
        kind = rng.choice(["name", "param", "value", "huge", "shape", "junk"])
        if kind == "name":
            body: Any = {"name": rng.choice(["", "no-such", "x" * 5000, "STATIC", None, 7, ["static"]])}
        elif kind == "param":
            body = {"name": "adaptive", "params": {rng.choice(["nope", "", "x" * 100]): 1}}
        elif kind == "value":
            body = {"name": "adaptive", "params": {rng.choice(["tau_ms", "min_tile_px"]):
                                                   rng.choice([-1, -1e9, "fast", None, [], True, 0.5])}}
            if body["params"].get("tau_ms") == 0.5:
                body["params"] = {"min_tile_px": 0.5}
        elif kind == "huge":
            value = rng.choice([_huge_int_text(rng), "1e999", "-1e999", "NaN", "Infinity"])
            text = '{"name": "adaptive", "params": {"tau_ms": ' + value + "}}"
            return Request("balancer.huge", "PUT", "/api/balancer", headers={"content-type": "application/json"},
                           content=text.encode())
        elif kind == "shape":
            body = rng.choice([[], "static", {"name": "static", "params": []}, {"name": "static", "params": "x"},
                               {"name": "static", "extra": 1}])
        else:
            label, text = self.junk_text()
            return Request(f"balancer.text.{label}", "PUT", "/api/balancer",
                           headers={"content-type": "application/json"}, content=text.encode("utf-8", "surrogatepass"))
        return Request(f"balancer.{kind}", "PUT", "/api/balancer", headers={"content-type": "application/json"},
                       content=json.dumps(body).encode())

