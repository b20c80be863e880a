"""``python -m bench.hostile --messages N [--seed S] [--json OUT]``: hostile input at volume.

A coordinator with ``--nodes`` real local render nodes (``--codec png``, ``--size`` small, a token
set) keeps rendering while a seeded storm of at least ``N`` malformed messages
(:mod:`bench.hostile_cases`) hits it from every side at once:

* ``/ws/node`` before the hello (each on a new socket), after a hello, and from nodes that loaded
  the scene and answer a real ``render`` wrongly (truncated, oversized, corrupt and wrong-size
  tiles, wrong codecs, tiles of frames or rects not assigned, duplicates, decompression bombs);
  after each bad message a sentinel follows, so a bad message the coordinator ignored shows as a
  close that names the sentinel;
* ``/ws/view``: bad camera, latency and unknown input, each to be answered by an ``error``;
* the REST API: bad bodies, queries, methods, paths, content types and tokens, each to get a 4xx.

Meanwhile a client turns the camera through a few reference cameras, and a well-behaved viewer keeps
every frame it is sent; each must equal ``python -m node --render-once`` of one of those cameras,
pixel for pixel, and after the storm ``GET /api/frame.png`` for each camera must too. The
coordinator's RSS (``/proc/PID/status`` VmRSS) is taken before the storm, after its first tenth
(the warm-up) and after it, with only the real nodes and viewers connected, and sampled during it.

It prints and writes (``--json``) the figures: messages per endpoint and family, close codes and a
sample reason per family, closes without a reason, messages left unanswered, HTTP statuses and
5xx, tracebacks in the coordinator's log, whether it crashed, RSS, frames checked and how many were
exact; and whether each goal is met (it exits 1 if one is missed): all of those zero, every frame
exact, RSS after the storm within 5 % + 4 MB of RSS after its warm-up. ``tests/test_fuzz.py`` runs
:func:`run_storm` against a coordinator of its own, so the test and the benchmark drive the same code.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import math
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from PIL import Image
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from bench.hostile_cases import Bad, Frames, HostileCases, Request
from bench.images import viewer_frame_image
from bench.live import render_once
from bench.processes import orbit, start_coordinator
from bench.soak import proc_figures
from tessera.cli_values import size_parser
from tessera.geometry import Rect
from tessera.wire.protocol import unpack_frame

#: Shares of the messages: node before hello, node after hello, viewer, REST.
SHARES = {"node_first": 0.15, "node_after": 0.30, "viewer": 0.35, "rest": 0.20}
#: Concurrent peers per kind.
WORKERS = {"node_first": 2, "node_after": 3, "node_owed": 1, "viewer": 2, "rest": 2}
#: One node that loads the scene and answers a render wrongly per this many messages.
MESSAGES_PER_OWED_SESSION = 250
#: Bad messages a viewer sends before reading their answers, and per connection.
VIEWER_BATCH, VIEWER_SESSION = 20, 200
#: Longest wait for any one answer (s).
ANSWER_TIMEOUT_S = 20.0
#: Camera changes per second while the storm lasts (the real nodes keep rendering).
CAMERA_HZ = 10.0
#: Close codes that carry no verdict (normal, none, abnormal).
EMPTY_CLOSES = {1000, 1005, 1006}
SENTINEL = json.dumps({"type": "sentinel"})
#: What the coordinator's close names when it was the sentinel that closed the socket.
SENTINEL_REASON = "'sentinel'"
#: The first tenth of the storm warms the coordinator up (Pillow loads its format plugins for the
#: first undecodable tile, pydantic builds its error paths, …); RSS after the whole storm may exceed
#: RSS after that tenth by this fraction, plus RSS_SLACK_KB (allocator noise while frames render).
WARMUP_SHARE, RSS_GROWTH_GOAL, RSS_SLACK_KB = 0.1, 0.05, 4 * 1024


def camera_key(camera: dict[str, Any]) -> tuple[float, ...]:
    vectors = (float(v) for name in ("eye", "target", "up") for v in camera.get(name, (0.0, 1.0, 0.0)))
    return (*vectors, float(camera.get("fovy_deg", 45.0)))


@dataclass
class References:
    """``python -m node --render-once --interactive`` of a few cameras: every frame must equal one of
    them (the coordinator runs ``--still-samples 1``: its still is that frame too)."""

    cameras: list[dict[str, Any]]
    images: list[np.ndarray]

    @classmethod
    def render(cls, scene: str, bounds: list[list[float]], size: tuple[int, int], count: int = 3) -> References:
        lo, hi = np.asarray(bounds, dtype=float)
        center, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
        eye = center + np.array([0.0, 0.4 * radius, 2.6 * radius])
        base = {"eye": eye.tolist(), "target": center.tolist(), "up": [0.0, 1.0, 0.0], "fovy_deg": 45.0}
        cameras = [orbit(base, 2.0 * math.pi * i / count) for i in range(count)]
        with ThreadPoolExecutor(count) as pool:
            images = list(pool.map(lambda camera: render_once(scene, camera, size, "--interactive"), cameras))
        return cls(cameras, images)

    def image_for(self, camera: dict[str, Any]) -> np.ndarray | None:
        key = camera_key(camera)
        return next((image for c, image in zip(self.cameras, self.images, strict=True) if camera_key(c) == key),
                    None)

    def tile_for(self, camera: dict[str, Any], rect: Rect) -> np.ndarray | None:
        """The reference pixels of ``rect`` for ``camera``, when it is one of ours."""
        image = self.image_for(camera)
        return None if image is None else image[rect.y:rect.y1, rect.x:rect.x1]

    def describe(self, frame_id: int, message: bytes) -> str:
        """Which tiles of a frame that equals no reference differ from the closest one, and their nodes."""
        image = viewer_frame_image(message)
        closest = min(self.images, key=lambda ref: int(np.abs(image.astype(np.int16) - ref).max()))
        frame = unpack_frame(message)
        tiles = [f"{entry.rect.as_list()} by slot {entry.node}: "
                 f"{int(np.abs(image[r.y:r.y1, r.x:r.x1].astype(np.int16) - closest[r.y:r.y1, r.x:r.x1]).max())}"
                 for entry, _ in frame.tiles for r in [entry.rect]]
        return f"frame {frame_id} (still: {frame.still}): " + "; ".join(tiles)

    def match(self, image: np.ndarray) -> tuple[bool, int]:
        """(equal to one reference, smallest largest channel difference over the references)."""
        diffs = [int(np.abs(image.astype(np.int16) - ref.astype(np.int16)).max()) if image.shape == ref.shape
                 else 255 for ref in self.images]
        return min(diffs) == 0, min(diffs)


@dataclass
class Tally:
    """What the storm sent and how each message was answered."""

    sent: Counter[str] = field(default_factory=Counter)
    labels: Counter[str] = field(default_factory=Counter)
    close_codes: Counter[int] = field(default_factory=Counter)
    closes_without_reason: list[str] = field(default_factory=list)
    unanswered: Counter[str] = field(default_factory=Counter)
    viewer_errors: int = 0
    viewer_closed: int = 0
    http_status: Counter[int] = field(default_factory=Counter)
    http_5xx: list[str] = field(default_factory=list)
    http_accepted: list[str] = field(default_factory=list)
    owed_sessions: int = 0
    problems: list[str] = field(default_factory=list)
    reasons: dict[str, str] = field(default_factory=dict)

    def problem(self, text: str) -> None:
        if len(self.problems) < 50:
            self.problems.append(text[:300])

    def closed(self, label: str, code: int | None, reason: str) -> None:
        """A socket closed by the coordinator after the bad message ``label``."""
        if code is None or code in EMPTY_CLOSES or not reason.strip():
            if len(self.closes_without_reason) < 50:
                self.closes_without_reason.append(f"{label}: code {code}, reason {reason!r}")
            return
        self.close_codes[code] += 1
        self.reasons.setdefault(label, f"{code} {reason}")
        if SENTINEL_REASON in reason:
            self.unanswered[label] += 1


class Storm:
    """The hostile peers, the camera mover, the frame watcher and the RSS sampler, on one event loop."""

    def __init__(self, url: str, token: str | None, messages: int, seed: int, references: References,
                 pid: int) -> None:
        self.url, self.ws_url = url, url.replace("http://", "ws://", 1)
        self.token, self.references, self.pid = token, references, pid
        self.cases = HostileCases(seed, token)
        self.quotas = {kind: math.ceil(messages * share) for kind, share in SHARES.items()}
        self.quotas["node_owed"] = max(2, messages // MESSAGES_PER_OWED_SESSION)
        self.left = dict.fromkeys(self.quotas, 0)
        self.tally = Tally()
        self.frames: dict[int, bytes] = {}
        self.last_frame = 0
        self.rss: list[int] = []
        self.auth = {"Authorization": f"Bearer {token}"} if token else {}
        self._stop = asyncio.Event()

    # ------------------------------------------------------------------------------- helpers
    def _connect(self, path: str, auth: bool = False) -> Any:
        headers = self.auth if auth else {}
        return connect(self.ws_url + path, max_size=64 << 20, open_timeout=ANSWER_TIMEOUT_S,
                       close_timeout=5, additional_headers=headers, ping_interval=None)

    async def _closed(self, ws: ClientConnection) -> tuple[int | None, str]:
        """Read until the coordinator closes; its code and reason (None: no close frame)."""
        try:
            async with asyncio.timeout(ANSWER_TIMEOUT_S):
                while True:
                    await ws.recv()
        except ConnectionClosed as closed:
            return (closed.rcvd.code, closed.rcvd.reason) if closed.rcvd else (None, "")
        except TimeoutError:
            return None, "no close within the timeout"

    async def _next_json(self, ws: ClientConnection, kind: str) -> dict[str, Any]:
        async with asyncio.timeout(ANSWER_TIMEOUT_S):
            while True:
                message = await ws.recv()
                if isinstance(message, str) and (data := json.loads(message)).get("type") == kind:
                    return data

    def _take(self, kind: str) -> bool:
        if self.left[kind] <= 0:
            return False
        self.left[kind] -= 1
        return True

    def _count(self, endpoint: str, bad: Bad | Request) -> None:
        self.tally.sent[endpoint] += 1
        self.tally.labels[bad.label] += 1

    async def _guard(self, what: str, work: Callable[[], Awaitable[None]]) -> None:
        """Run one peer; a failure of the driver's own (a timeout, a refused connection) is recorded."""
        try:
            await work()
        except (ConnectionClosed, InvalidStatus, OSError, TimeoutError, ValueError) as exc:
            self.tally.problem(f"{what}: {type(exc).__name__}: {exc}")

    # ------------------------------------------------------------------------------- nodes
    async def node_first(self) -> None:
        while self._take("node_first"):
            bad = self.cases.node_first()

            async def one(bad: Bad = bad) -> None:
                async with self._connect("/ws/node") as ws:
                    self._count("node", bad)
                    await ws.send(bad.data)
                    self.tally.closed(bad.label, *await self._closed(ws))
            await self._guard("node before hello", one)

    async def _hello(self, ws: ClientConnection) -> dict[str, Any]:
        await ws.send(json.dumps(self.cases.hello()))
        await self._next_json(ws, "welcome")
        return await self._next_json(ws, "load_scene")

    async def _send_then_sentinel(self, ws: ClientConnection, bads: list[Bad]) -> None:
        with contextlib.suppress(ConnectionClosed):
            for bad in bads:
                self._count("node", bad)
                await ws.send(bad.data)
            await ws.send(SENTINEL)
        self.tally.closed(bads[-1].label, *await self._closed(ws))

    async def node_after(self) -> None:
        while self._take("node_after"):
            bad = self.cases.node_after_hello(Frames(self.last_frame))

            async def one(bad: Bad = bad) -> None:
                async with self._connect("/ws/node") as ws:
                    await self._hello(ws)
                    await self._send_then_sentinel(ws, [bad])
            await self._guard("node after hello", one)

    async def node_owed(self) -> None:
        """Nodes that load the scene, are given tiles, and answer them wrongly."""
        while self._take("node_owed"):
            async def one() -> None:
                async with self._connect("/ws/node") as ws:
                    await self._hello(ws)
                    bounds = self.references.cameras[0]["target"]
                    await ws.send(json.dumps({"type": "scene_ready", "triangles": 1,
                                              "bounds": [bounds, [b + 1.0 for b in bounds]]}))
                    render = await self._next_json(ws, "render")
                    self.tally.owed_sessions += 1
                    await self._send_then_sentinel(ws, self.cases.node_owed(render, self.references.tile_for))
            await self._guard("node owed tiles", one)

    # ------------------------------------------------------------------------------- viewers
    async def viewer(self) -> None:
        while self.left["viewer"] > 0:
            async def session() -> None:
                async with self._connect("/ws/view", auth=True) as ws:
                    await self._next_json(ws, "hello")
                    sent = 0
                    while sent < VIEWER_SESSION and self.left["viewer"] > 0:
                        batch = [self.cases.viewer() for _ in range(min(VIEWER_BATCH, self.left["viewer"]))]
                        self.left["viewer"] -= len(batch)
                        try:
                            for bad in batch:
                                self._count("viewer", bad)
                                await ws.send(bad.data)
                        except ConnectionClosed:
                            pass  # closed by the coordinator: read why below
                        if not await self._errors(ws, batch):
                            return
                        sent += len(batch)
            await self._guard("viewer", session)

    async def _errors(self, ws: ClientConnection, batch: list[Bad]) -> bool:
        """Read one ``error`` per message of ``batch`` (frames and camera news in between); a close
        with a reason answers the rest (False: the socket was closed)."""
        answered = 0
        try:
            async with asyncio.timeout(ANSWER_TIMEOUT_S):
                while answered < len(batch):
                    message = await ws.recv()
                    if isinstance(message, str) and (data := json.loads(message)).get("type") == "error":
                        if not str(data.get("message", "")).strip():
                            self.tally.closes_without_reason.append(f"{batch[answered].label}: empty error")
                        answered += 1
                        self.tally.viewer_errors += 1
        except ConnectionClosed as closed:
            # the message that closed it is one of the rest (the errors queued before are not sent)
            code, reason = (closed.rcvd.code, closed.rcvd.reason) if closed.rcvd else (None, "")
            self.tally.closed("viewer.closed", code, reason)
            self.tally.viewer_closed += len(batch) - answered
            return False
        except TimeoutError:
            for bad in batch[answered:]:
                self.tally.unanswered[bad.label] += 1
            raise
        return True

    # ------------------------------------------------------------------------------- REST
    async def rest(self, http: httpx.AsyncClient) -> None:
        while self._take("rest"):
            request = self.cases.rest()
            headers = dict(request.headers) if request.label == "token" else {**self.auth, **request.headers}
            self._count("rest", request)
            try:
                response = await http.request(request.method, request.path, params=request.params, headers=headers,
                                              content=request.content)
            except httpx.HTTPError as exc:
                self.tally.problem(f"REST {request.label}: {type(exc).__name__}: {exc}")
                continue
            status = response.status_code
            self.tally.http_status[status] += 1
            if status >= 500:
                self.tally.http_5xx.append(f"{request.label} {request.method} {request.path[:80]}: {status} "
                                           f"{response.text[:200]}")
            elif status < 400:
                self.tally.http_accepted.append(f"{request.label} {request.method} {request.path[:80]} "
                                                f"{(request.content or b'')[:120]!r}: {status}")
            elif not response.content.strip():
                self.tally.closes_without_reason.append(f"{request.label}: {status} with an empty body")

    # ------------------------------------------------------------------------------- the honest side
    async def mover(self, http: httpx.AsyncClient) -> None:
        """Turns the camera through the reference cameras while the storm lasts."""
        index = 0
        while not self._stop.is_set():
            index += 1
            camera = self.references.cameras[index % len(self.references.cameras)]
            (await http.put("/api/camera", json=camera, headers=self.auth)).raise_for_status()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), 1.0 / CAMERA_HZ)

    async def watcher(self, ready: asyncio.Event) -> None:
        """A well-behaved viewer: keeps every frame it is sent (by id)."""
        async with self._connect("/ws/view", auth=True) as ws:
            await self._next_json(ws, "hello")
            ready.set()
            while not self._stop.is_set():
                try:
                    message = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                if isinstance(message, bytes):
                    frame_id = unpack_frame(message).frame_id
                    self.frames.setdefault(frame_id, message)
                    self.last_frame = max(self.last_frame, frame_id)

    async def sampler(self) -> None:
        while not self._stop.is_set():
            if (sample := proc_figures(self.pid)) is not None:
                self.rss.append(sample["rss_kb"])
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), 0.25)

    # ------------------------------------------------------------------------------- the run
    async def run(self, real_nodes: int) -> dict[str, Any]:
        async with httpx.AsyncClient(base_url=self.url, timeout=ANSWER_TIMEOUT_S) as http:
            await self._check_api_frames(http)  # from a reference camera on: every frame the watcher sees
            rss_before = await self._settled_rss(http, real_nodes, viewers=0)
            started = time.monotonic()
            ready = asyncio.Event()
            background = [asyncio.create_task(self.watcher(ready)), asyncio.create_task(self.sampler())]
            await asyncio.wait_for(ready.wait(), ANSWER_TIMEOUT_S)
            background.append(asyncio.create_task(self.mover(http)))
            finished: dict[str, float] = {}

            async def peers(kind: str, make: Callable[[], Awaitable[None]]) -> None:
                await asyncio.gather(*(make() for _ in range(WORKERS[kind])))
                finished[kind] = round(time.monotonic() - started, 2)
            warm = {kind: math.ceil(quota * WARMUP_SHARE) for kind, quota in self.quotas.items()}
            rss_warm = 0
            for part in (warm, {kind: quota - warm[kind] for kind, quota in self.quotas.items()}):
                self.left = dict(part)
                await asyncio.gather(peers("node_first", self.node_first), peers("node_after", self.node_after),
                                     peers("node_owed", self.node_owed), peers("viewer", self.viewer),
                                     peers("rest", lambda: self.rest(http)))
                if not rss_warm:
                    rss_warm = await self._settled_rss(http, real_nodes, viewers=1)
            storm_s = time.monotonic() - started
            self._stop.set()
            await asyncio.gather(*background)
            api_checked, api_exact = await self._check_api_frames(http)
            rss_after = await self._settled_rss(http, real_nodes, viewers=0)
            healthy = (await http.get("/healthz")).status_code == 200
            stats = (await http.get("/api/stats", headers=self.auth)).json()
        frames_exact, worst, wrong = 0, 0, []
        for frame_id, message in sorted(self.frames.items()):
            exact, diff = self.references.match(viewer_frame_image(message))
            frames_exact += exact
            worst = max(worst, diff)
            if not exact and len(wrong) < 5:
                wrong.append(self.references.describe(frame_id, message))
        t = self.tally
        messages = sum(t.sent.values())
        return {
            "messages": messages, "sent": dict(t.sent), "families": dict(sorted(t.labels.items())),
            "storm_s": round(storm_s, 2), "finished_s": finished, "messages_per_s": round(messages / storm_s, 1),
            "close_codes": {str(k): v for k, v in sorted(t.close_codes.items())},
            "viewer_errors": t.viewer_errors, "viewer_closed": t.viewer_closed,
            "closes_without_reason": t.closes_without_reason, "unanswered": dict(t.unanswered),
            "http_status": {str(k): v for k, v in sorted(t.http_status.items())},
            "http_5xx": t.http_5xx, "http_accepted": t.http_accepted, "owed_sessions": t.owed_sessions,
            "driver_problems": t.problems, "reasons": dict(sorted(t.reasons.items())),
            "frames_checked": len(self.frames) + api_checked, "frames_exact": frames_exact + api_exact,
            "frames_worst_diff": worst, "frames_wrong": wrong, "api_frames_checked": api_checked,
            "api_frames_exact": api_exact, "rss_kb_before": rss_before, "rss_kb_warm": rss_warm,
            "rss_kb_peak": max([rss_before, *self.rss]), "rss_kb_after": rss_after,
            "coordinator_healthy": healthy, "nodes_after": len(stats["nodes"]),
        }

    async def _settled_rss(self, http: httpx.AsyncClient, real_nodes: int, viewers: int) -> int:
        """RSS (kB) once only the real nodes and ``viewers`` viewers are connected (bounded wait)."""
        deadline = time.monotonic() + ANSWER_TIMEOUT_S
        while time.monotonic() < deadline:
            stats = (await http.get("/api/stats", headers=self.auth)).json()
            if len(stats["nodes"]) == real_nodes and stats["viewers"] == viewers:
                break
            await asyncio.sleep(0.1)
        else:
            self.tally.problem(f"peers still connected after the storm: {len(stats['nodes'])} nodes, "
                               f"{stats['viewers']} viewers")
        sample = proc_figures(self.pid)
        return sample["rss_kb"] if sample else 0

    async def _check_api_frames(self, http: httpx.AsyncClient) -> tuple[int, int]:
        """``GET /api/frame.png`` after setting each reference camera: (checked, exact)."""
        checked = exact = 0
        for camera, reference in zip(self.references.cameras, self.references.images, strict=True):
            frame = (await http.put("/api/camera", json=camera, headers=self.auth)).raise_for_status().json()["frame"]
            response = await http.get("/api/frame.png", params={"after": frame}, headers=self.auth)
            response.raise_for_status()
            image = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
            checked += 1
            exact += image.shape == reference.shape and bool(np.array_equal(image, reference))
        return checked, exact


def run_storm(url: str, token: str | None, messages: int, seed: int, references: References, pid: int,
              real_nodes: int) -> dict[str, Any]:
    """The storm against a running coordinator (process ``pid``, ``real_nodes`` ready nodes)."""
    return asyncio.run(Storm(url, token, messages, seed, references, pid).run(real_nodes))


def shortfalls(figures: dict[str, Any], minimum_messages: int) -> list[str]:
    """The goals a run missed (empty: every goal met)."""
    out = []
    if figures["messages"] < minimum_messages:
        out.append(f"{figures['messages']} messages sent, fewer than {minimum_messages}")
    for key in ("http_5xx", "http_accepted", "closes_without_reason", "driver_problems"):
        if figures[key]:
            out.append(f"{key}: {figures[key][:5]}")
    if figures["unanswered"]:
        out.append(f"messages the coordinator ignored: {figures['unanswered']}")
    if figures.get("tracebacks", 0):
        out.append(f"{figures['tracebacks']} tracebacks in the coordinator's log")
    if figures.get("crashed") or not figures["coordinator_healthy"]:
        out.append("the coordinator crashed or stopped answering /healthz")
    if figures["frames_exact"] != figures["frames_checked"] or figures["api_frames_checked"] == 0:
        out.append(f"{figures['frames_checked'] - figures['frames_exact']} of {figures['frames_checked']} frames "
                   f"differ from --render-once (largest difference {figures['frames_worst_diff']})")
    limit = figures["rss_kb_warm"] * (1 + RSS_GROWTH_GOAL) + RSS_SLACK_KB
    if figures["rss_kb_after"] > limit:
        out.append(f"RSS {figures['rss_kb_after']} kB after the storm, over {limit:.0f} kB "
                   f"(after its first tenth: {figures['rss_kb_warm']} kB)")
    return out


def report(figures: dict[str, Any]) -> str:
    mb = 1024.0
    lines = [
        f"hostile storm: {figures['messages']} messages in {figures['storm_s']} s "
        f"({figures['messages_per_s']}/s), seed {figures.get('seed')}",
        "  sent            " + ", ".join(f"{k} {v}" for k, v in sorted(figures["sent"].items())),
        f"  nodes given real tiles, answering them wrongly: {figures['owed_sessions']}",
        f"  viewer input    {figures['viewer_errors']} answered by an error, {figures['viewer_closed']} by a close",
        f"  close codes     {figures['close_codes']}",
        f"  HTTP statuses   {figures['http_status']}",
        f"  5xx             {len(figures['http_5xx'])}   2xx to bad input: {len(figures['http_accepted'])}",
        f"  closes or errors without a reason: {len(figures['closes_without_reason'])}   "
        f"unanswered: {sum(figures['unanswered'].values())}",
        f"  tracebacks      {figures.get('tracebacks', 'n/a')}   crashed: {figures.get('crashed', 'n/a')}",
        f"  RSS             {figures['rss_kb_before'] / mb:.1f} MB before, {figures['rss_kb_warm'] / mb:.1f} after "
        f"the first tenth, {figures['rss_kb_peak'] / mb:.1f} peak, {figures['rss_kb_after'] / mb:.1f} after",
        f"  frames          {figures['frames_exact']} of {figures['frames_checked']} exact "
        f"({figures['api_frames_exact']} of {figures['api_frames_checked']} from GET /api/frame.png after the storm)",
    ]
    missed = shortfalls(figures, figures.get("minimum_messages", 0))
    lines.append("  goals           " + ("all met" if not missed else "MISSED: " + "; ".join(missed)))
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.hostile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--messages", type=int, default=10_000, help="hostile messages to send (default 10000)")
    parser.add_argument("--seed", type=int, default=1, help="generator seed: the same seed sends the same messages")
    parser.add_argument("--nodes", type=int, default=2, help="real local render nodes (default 2)")
    parser.add_argument("--scene", default="builtin:spheres")
    parser.add_argument("--size", type=size_parser(16, 4096), default=(160, 120), help="frame size (default 160x120)")
    parser.add_argument("--token", default="hostile-bench", help="the coordinator's token ('' for none)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--log-dir", type=Path, help="keep the coordinator's log here (default: a temporary folder)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    token = args.token or None
    with tempfile.TemporaryDirectory() as tmp:
        log_dir = args.log_dir or Path(tmp)
        log_dir.mkdir(parents=True, exist_ok=True)
        server_args = ["--scene", args.scene, "--size", f"{args.size[0]}x{args.size[1]}", "--codec", "png",
                       "--still-samples", "1", "--local-nodes", str(args.nodes)] + (["--token", token] if token else [])
        coordinator, url = start_coordinator(server_args, log_path=log_dir / "coordinator.log")
        try:
            headers = {"Authorization": f"Bearer {token}"} if token else {}
            with httpx.Client(base_url=url, headers=headers, timeout=30) as client:
                deadline = time.monotonic() + 180
                while sum(n["state"] == "ready" for n in client.get("/api/stats").json()["nodes"]) < args.nodes:
                    if time.monotonic() > deadline or coordinator.process.poll() is not None:
                        raise RuntimeError("the nodes did not get ready:\n" + coordinator.output())
                    time.sleep(0.1)
                bounds = client.get("/api/camera").json()["bounds"]
            references = References.render(args.scene, bounds, args.size)
            figures = run_storm(url, token, args.messages, args.seed, references, coordinator.pid, args.nodes)
            figures["crashed"] = coordinator.process.poll() is not None
        finally:
            coordinator.stop()
        figures.update(seed=args.seed, minimum_messages=args.messages, tracebacks=coordinator.tracebacks,
                       first_traceback=coordinator.first_traceback, command=" ".join(["python -m bench.hostile",
                                                                                      *(argv or sys.argv[1:])]))
    print(report(figures))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1))
    return 0 if not shortfalls(figures, args.messages) else 1


if __name__ == "__main__":
    sys.exit(main())
