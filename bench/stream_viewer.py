"""The scripted viewer of ``python -m bench.stream`` (issue 21): it offers one transport and
decodes every interactive frame it gets as it comes — TFRM tiles with
:func:`bench.images.viewer_frame_image`, TVID access units with PyAV (``av.CodecContext.create(codec,
"r")``, one ``av.Packet`` each; a unit that fails to decode, or any unit after one until a keyframe, is
lost, and the viewer then sends ``keyframe``) — and keeps the still frames it gets."""

from __future__ import annotations

import io
import json
import math
import queue
import threading
import time
from typing import Any

import av
import httpx
import numpy as np
import websockets.sync.client as ws_client
from PIL import Image

from bench.images import viewer_frame_image
from bench.live import ScriptedViewer
from tessera.video.yuv_frame import decoded_planes, rgb_of_yuv420
from tessera.wire.protocol import unpack_frame
from tessera.wire.stream_messages import KeyframeRequest, StreamOffer, StreamReport
from tessera.wire.video import is_video, unpack_video

#: seconds a viewer waits for the coordinator's ``stream`` answer to its offer
CHOICE_TIMEOUT_S = 10.0
#: seconds between two ``stream_report`` s of a video viewer (as web/video.js)
REPORT_S = 1.0


class StreamViewer(ScriptedViewer):
    """A :class:`bench.live.ScriptedViewer` that offers ``transport`` and decodes what it gets.

    ``decoded``: per interactive frame decoded, its time (perf_counter s), frame id, message bytes,
    input number and keyframe flag; ``lost``: video frames that did not decode; ``samples``: the
    decoded images (h, w, 3) of frames taken for PSNR (one each ``sample_every_s`` from
    ``sample_from`` on), keyed by frame id, with their input numbers in ``sample_inputs``;
    ``sources``: those frames' composites from ``/api/frame.png`` when ``http`` is given; ``stills``:
    the still frames that came (perf_counter s, frame id, input number, the TFRM message) and
    ``refinements`` the progressive still's other frames (perf_counter s, bytes)."""

    def __init__(self, ws: ws_client.ClientConnection, transport: str, http_url: str | None) -> None:
        self.transport = transport
        self.choice: dict[str, Any] | None = None
        self._chosen = threading.Event()
        self.decoded: list[dict[str, Any]] = []
        self.lost = 0
        self.keyframes = 0
        self.tfrm_after_choice = 0
        self.samples: dict[int, np.ndarray] = {}
        self.sample_inputs: dict[int, int] = {}
        self.sources: dict[int, np.ndarray] = {}
        self.cameras: dict[int, dict[str, Any]] = {}
        self.newest_video: int | None = None
        self.stills: list[tuple[float, int, int, bytes]] = []
        self._window: tuple[float, int, int] | None = None
        self.refinements: list[tuple[float, int]] = []
        self.sample_from = math.inf
        self.sample_every_s = math.inf
        self._decoder: Any = None
        self._waiting_for_key = True
        self._fetches: queue.Queue[int | None] = queue.Queue()
        self._fetcher = threading.Thread(target=self._fetch_sources, args=(http_url,), daemon=True) \
            if http_url is not None else None
        super().__init__(ws)
        if self._fetcher is not None:
            self._fetcher.start()

    def offer(self) -> dict[str, Any]:
        """Send ``stream_offer`` with this viewer's codec (tiles: none) and wait for the answer
        (tiles: up to :data:`CHOICE_TIMEOUT_S`, then go on with tiles without one)."""
        codecs = () if self.transport == "tiles" else (self.transport,)
        if self.transport != "tiles":
            self._decoder = av.CodecContext.create(self.transport, "r")
        self.ws.send(StreamOffer(codecs=codecs).to_text())
        if not self._chosen.wait(CHOICE_TIMEOUT_S):
            if self.transport == "tiles":   # a coordinator without video streams sends tiles anyway
                return {"type": "stream", "transport": "tiles", "reason": "no answer to the offer"}
            raise RuntimeError(f"no 'stream' answer to the offer of {list(codecs)} within {CHOICE_TIMEOUT_S:.0f} s")
        assert self.choice is not None
        return self.choice

    def send_camera(self, camera: dict[str, Any]) -> None:
        super().send_camera(camera)
        self.cameras[self.seq] = camera

    def counts(self) -> tuple[float, int, int]:
        """Now (perf_counter s), bytes received and frames decoded so far."""
        with self.lock:
            return time.perf_counter(), sum(f["bytes"] for f in self.decoded), len(self.decoded)

    def report(self, since: tuple[float, int, int]) -> tuple[float, int, int]:
        """Send ``stream_report`` (as a browser viewer does each second) over the window since
        ``since`` (:meth:`counts` then); the next window's start."""
        now = self.counts()
        seconds = max(now[0] - since[0], 1e-3)
        self.ws.send(StreamReport(bytes_per_s=(now[1] - since[1]) / seconds, decoded_fps=(now[2] - since[2]) / seconds,
                                  decode_queue=0, frames_dropped=self.lost, frame=self.newest_video).to_text())
        return now

    def report_due(self, now: float) -> None:
        """A video viewer's ``stream_report`` each :data:`REPORT_S` from the first call (``now``:
        perf_counter s), as the page sends it."""
        if self.transport == "tiles":
            return
        if self._window is None:
            self._window = self.counts()
        elif now >= self._window[0] + REPORT_S:
            self._window = self.report(self._window)

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                message = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(message, str):
                control = json.loads(message)
                if control.get("type") == "stream":
                    self.choice = control
                    self._chosen.set()
            elif is_video(message):
                self._on_video(message)
            else:
                self._on_tiles(message)

    def _on_tiles(self, message: bytes) -> None:
        frame = unpack_frame(message)
        if frame.still or frame.samples:   # the still and its progressive refinements
            with self.lock:
                if frame.still:
                    self.stills.append((time.perf_counter(), frame.frame_id, frame.input_seq, message))
                else:
                    self.refinements.append((time.perf_counter(), len(message)))
            return
        if self.choice is not None:
            self.tfrm_after_choice += 1
        started = time.thread_time()
        image = viewer_frame_image(message)
        decode_ms = (time.thread_time() - started) * 1000.0
        self._record(frame.frame_id, len(message), frame.input_seq, False, image, decode_ms)

    def _on_video(self, message: bytes) -> None:
        frame = unpack_video(message)
        self.newest_video = frame.frame_id
        self.keyframes += frame.keyframe
        assert self._decoder is not None, "a video frame before the offer"
        if self._waiting_for_key and not frame.keyframe:
            self.lost += 1
            return
        packet = av.Packet(frame.data)
        packet.pts = frame.frame_id
        started = time.thread_time()
        try:
            pictures = self._decoder.decode(packet)
        except av.error.FFmpegError:
            pictures = []
        decode_ms = (time.thread_time() - started) * 1000.0
        if not pictures:
            self.lost += 1
            self._waiting_for_key = True
            self.ws.send(KeyframeRequest().to_text())
            return
        self._waiting_for_key = False
        for picture in pictures:
            self._record(frame.frame_id, len(message), frame.input_seq, frame.keyframe, picture, decode_ms)

    def _record(self, frame_id: int, size: int, input_seq: int, keyframe: bool, image: Any,
                decode_ms: float) -> None:
        """Note a decoded frame (``decode_ms``: this thread's CPU decoding it); keep its pixels (an
        ndarray or an ``av.VideoFrame``) when sampled."""
        now = time.perf_counter()
        with self.lock:
            self.decoded.append({"at": now, "id": frame_id, "bytes": size, "input": input_seq,
                                 "keyframe": keyframe, "decode_ms": decode_ms})
        if now >= self.sample_from:
            self.sample_from += self.sample_every_s
            pixels = image if isinstance(image, np.ndarray) else rgb_of_yuv420(decoded_planes(image),
                                                                                (image.width, image.height))
            with self.lock:
                self.samples[frame_id] = pixels
                self.sample_inputs[frame_id] = input_seq
            self._fetches.put(frame_id)

    def _fetch_sources(self, url: str) -> None:
        """The composites of the sampled frames, fetched as they are sampled (the coordinator keeps
        its newest 16 frames): a frame it no longer holds is left out."""
        with httpx.Client(base_url=url, timeout=30) as client:
            while (frame_id := self._fetches.get()) is not None:
                response = client.get("/api/frame.png", params={"after": frame_id, "timeout": 5})
                if response.status_code == 200 and int(response.headers["x-frame-id"]) == frame_id:
                    image = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
                    with self.lock:
                        self.sources[frame_id] = image

    def stop(self) -> None:
        super().stop()
        if self._fetcher is not None:
            self._fetches.put(None)
            self._fetcher.join(timeout=30)
