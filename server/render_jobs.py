"""Render jobs on the coordinator (issue 35): posters (one PNG up to 16384×16384) and films (an
H.264 MP4 of a camera path or an orbit), made by the sessions' users and drawn by the nodes beside
the sessions' frames (:class:`tessera.scheduling.job_scheduler.JobScheduler` hands out their tiles).

Each tile that comes back is one sample of one piece of a picture: it is decoded and added to the
piece's :class:`tessera.scheduling.refinement.Accumulator` on one worker thread (off the event
loop); a piece whose samples are all in is pasted, as their mean, into its picture; a poster
whole is written as PNG; a film's pictures are encoded in order (PyAV, libx264) into its MP4 as
they complete, and the scheduler is told, so it starts later pictures (only a few are held at
once). A poster's picture is held in memory up to :data:`MAPPED_PIXELS`, beyond in a file mapped
in the job's folder.

Bounds (4xx with the reason beyond them): ``--max-jobs`` jobs unfinished at once, a poster's side
``--max-poster-size``, a film's size ``--max-size`` (even sides, as H.264's 4:2:0 wants), its frames
``--max-film-frames``, samples 1…127. The outputs live in a temporary folder of the coordinator
process: render jobs survive nothing, and after a restart a job that was not finished reads as
failed, with that reason. A session keeps its last :data:`KEPT_JOBS` jobs; closing it ends and
deletes them.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import secrets
import shutil
import tempfile
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any, Protocol

import av
import numpy as np
from PIL import Image

from server.settings import MAX_TILE_BYTES_PER_PIXEL
from tessera.geometry import Camera
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.job_scheduler import JobScheduler
from tessera.scheduling.refinement import Accumulator, StillPlan
from tessera.scheduling.render_jobs import (
    CANCELLED,
    DONE,
    ERROR,
    JobItem,
    JobSpec,
    RenderWork,
    piece_side,
)
from tessera.wire.codec import Codec, decode

log = logging.getLogger("tessera.server")

#: Pictures larger than this (pixels) are held in a file mapped in the job's folder, not in memory.
MAPPED_PIXELS = 64 << 20
#: Jobs a session keeps listed (finished ones beyond it are forgotten, their files deleted, oldest first).
KEPT_JOBS = 16
#: x264's settings for a film: quality over speed within reason (one thread: the coordinator's CPU
#: is shared with the sessions' frames).
FILM_OPTIONS = {"preset": "veryfast", "crf": "18", "threads": "1"}
#: Samples of a poster when the still's count is adaptive (no fixed count to follow): the most an
#: adaptive still took at 1280x720 on the seven scenes of ``bench.picture`` (issue 37's figures).
DEFAULT_POSTER_SAMPLES = 16
#: Samples of a film's frame by default: one, the interactive frame's anti-aliasing (at full detail).
DEFAULT_FILM_SAMPLES = 1
#: What a job that was not finished reads as after a restart.
RESTART_REASON = "the coordinator restarted while it rendered (render jobs survive nothing): make it again"


class JobRefused(ValueError):
    """A job that cannot be made: ``status`` is the HTTP status to give, with the reason."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


class JobHost(Protocol):
    """What the jobs need of the service."""

    scheduler: JobScheduler

    @property
    def settings(self) -> Any: ...

    def apply(self) -> None:
        """Carry out the scheduler's actions."""


@dataclass
class RenderJob:
    """A job as its session lists it: ``work`` (None: a job from before a restart), its ``kind``,
    ``fps`` (a film's), output ``path`` and what went wrong."""

    job_id: str
    session: str
    kind: str
    work: RenderWork | None
    path: Path | None = None
    fps: float | None = None
    created: float = field(default_factory=time.time)
    failed: str | None = None

    def describe(self) -> dict[str, Any]:
        """``{"id", "kind", "state", "done", "total", "reason"?}`` (``total``: a film's frames, a
        poster's piece samples)."""
        if self.work is None:
            return {"id": self.job_id, "kind": self.kind, "state": ERROR, "done": 0, "total": 0, "node_ms": 0.0,
                    "reason": self.failed or RESTART_REASON}
        return {"id": self.job_id, "kind": self.kind, **self.work.describe()}

    def record(self) -> dict[str, Any]:
        """What a restart keeps of it: enough to say it failed."""
        return {"id": self.job_id, "kind": self.kind}


class JobPixels:
    """A job's pixels, on the worker thread only: the pieces' accumulators, the pictures being
    assembled, and the output (a poster's PNG, a film's MP4 encoder)."""

    def __init__(self, job: RenderJob, folder: Path) -> None:
        assert job.work is not None
        self.work, self.folder, self.job = job.work, folder, job
        self.samples = self.work.samples
        self._sums: dict[tuple[int, int], Accumulator] = {}
        self._pictures: dict[int, np.ndarray] = {}
        self._pieces: dict[int, int] = {}
        self._ready: dict[int, np.ndarray] = {}
        self._next = 0
        self._container: Any = None
        self._stream: Any = None

    def add(self, item: JobItem, payload: bytes, codec: Any) -> list[int]:
        """Sample ``item.sample`` of piece ``item.piece``'s tile bytes; returns the pictures now taken
        whole (a film's encoded, in order; a poster's written)."""
        rect, _ = self.work.pieces[item.piece]
        pixels = decode(payload, codec, rect.w, rect.h)
        key = (item.picture, item.piece)
        if self.samples > 1:
            sums = self._sums.setdefault(key, Accumulator((rect.w, rect.h)))
            sums.add(pixels)
            sums.finish_sample()
            if sums.count < self.samples:
                return []
            pixels = self._sums.pop(key).mean()
        picture = self._picture(item.picture)
        picture[rect.y:rect.y1, rect.x:rect.x1] = pixels
        self._pieces[item.picture] = self._pieces.get(item.picture, 0) + 1
        if self._pieces[item.picture] < len(self.work.pieces):
            return []
        del self._pieces[item.picture]
        self._ready[item.picture] = self._pictures.pop(item.picture)
        return self._take()

    def _picture(self, index: int) -> np.ndarray:
        picture = self._pictures.get(index)
        if picture is None:
            width, height = self.work.spec.size
            if width * height > MAPPED_PIXELS:
                picture = np.lib.format.open_memmap(self.folder / f"picture-{index}.npy", mode="w+",
                                                    dtype=np.uint8, shape=(height, width, 3))
            else:
                picture = np.zeros((height, width, 3), np.uint8)
            self._pictures[index] = picture
        return picture

    def _take(self) -> list[int]:
        taken = []
        while self._next in self._ready:
            picture = self._ready.pop(self._next)
            if self.job.kind == "poster":
                self._write_png(picture)
            else:
                self._encode(picture)
            taken.append(self._next)
            self._next += 1
        if self.job.kind == "film" and self._next == len(self.work.spec.cameras):
            self._close_film()
        return taken

    def _write_png(self, picture: np.ndarray) -> None:
        assert self.job.path is not None
        height, width = picture.shape[:2]
        written = self.job.path.with_suffix(".part")
        Image.frombuffer("RGB", (width, height), np.ascontiguousarray(picture), "raw", "RGB", 0, 1).save(
            written, format="PNG", compress_level=1)
        written.replace(self.job.path)
        with contextlib.suppress(OSError):
            (self.folder / "picture-0.npy").unlink()

    def _encode(self, picture: np.ndarray) -> None:
        if self._container is None:
            assert self.job.path is not None and self.job.fps is not None
            width, height = self.work.spec.size
            self._container = av.open(str(self.job.path.with_suffix(".part")), "w", format="mp4")
            rate = Fraction(self.job.fps).limit_denominator(1001)
            self._stream = self._container.add_stream("libx264", rate=rate, options=dict(FILM_OPTIONS))
            self._stream.width, self._stream.height, self._stream.pix_fmt = width, height, "yuv420p"
            self._stream.time_base = 1 / rate
        frame = av.VideoFrame.from_ndarray(picture, format="rgb24").reformat(format="yuv420p")
        frame.pts = self._next
        for packet in self._stream.encode(frame):
            self._container.mux(packet)

    def _close_film(self) -> None:
        if self._container is None:
            return
        for packet in self._stream.encode(None):
            self._container.mux(packet)
        self._container.close()
        self._container = None
        assert self.job.path is not None
        self.job.path.with_suffix(".part").replace(self.job.path)

    def close(self) -> None:
        """Drop what is held (a job ended early): the encoder closed, nothing written."""
        if self._container is not None:
            with contextlib.suppress(Exception):
                self._container.close()
            self._container = None
        self._sums.clear()
        self._pictures.clear()
        self._ready.clear()


class RenderJobs:
    """Every session's render jobs (:class:`RenderJob`), their pixels (:class:`JobPixels`) and the
    worker thread; made and answered by the posters and recordings routes."""

    def __init__(self, host: JobHost, max_jobs: int) -> None:
        self.host, self.max_jobs = host, max_jobs
        self.folder = Path(tempfile.mkdtemp(prefix="tessera-jobs-"))
        self.jobs: dict[str, RenderJob] = {}
        self._pixels: dict[str, JobPixels] = {}
        self._worker = ThreadPoolExecutor(1, thread_name_prefix="tessera-jobs")

    # ----------------------------------------------------------------- made and read
    def start(self, session_id: str, kind: str, cameras: list[Camera], size: tuple[int, int], samples: int,
              frames: Any, fps: float | None = None) -> RenderJob:
        """A new job of ``session_id`` (its scheduler side ``frames``: scene, state, clip, selection
        now) drawing ``cameras`` at ``size`` from ``samples`` samples each; JobRefused beyond
        ``--max-jobs`` (503), for a session whose scene is not loaded or a sort-last point cloud (409)."""
        unfinished = sum(1 for job in self.jobs.values() if job.work is not None and not job.work.finished)
        if unfinished >= self.max_jobs:
            raise JobRefused(503, f"{unfinished} render jobs are under way, the most this coordinator takes "
                                  "(--max-jobs); wait for one to end or cancel one")
        if frames.camera is None or not frames.ready:
            raise JobRefused(409, "no node has loaded the session's scene yet")
        sort_last = frames.mode.job_nodes() is not None
        if sort_last and frames.point_bounds is not None:
            raise JobRefused(409, "posters and films of a point cloud are drawn in sort-first, not sort-last (its "
                                  "layers are shaded once merged, whole)")
        now = time.monotonic()
        state = None if frames.scene is None else frames.scene.bind(now)
        spec = JobSpec(kind, session_id, frames.scene_key, cameras, size, StillPlan(samples), state, frames.clip,
                       frames.highlight)
        rates = [node.ms_per_px for node in self.host.scheduler.nodes.values() if node.ms_per_px is not None]
        job_id = secrets.token_urlsafe(9)
        # a piece's tile, raw or PNG (at most a little more than raw), fits in a node's message
        # (sort-last: a depth tile, colour and depth)
        per_px = MAX_TILE_BYTES_PER_PIXEL if sort_last else 3.5
        fitting = int(math.sqrt(max(self.host.settings.node_message_bytes - (1 << 20), 1 << 16) / per_px)) // 2 * 2
        work = RenderWork(job_id, spec, side=min(piece_side(max(rates, default=None)), fitting))
        suffix = "png" if kind == "poster" else "mp4"
        job = RenderJob(job_id, session_id, kind, work, self.folder / f"{job_id}.{suffix}", fps)
        self.jobs[job_id] = job
        self._pixels[job_id] = JobPixels(job, self.folder)
        self._forget_old(session_id)
        self.host.scheduler.add_job(work, now)
        self.host.apply()
        log.info("session %s… %s %s: %dx%d, %d picture(s), %d piece(s) of %d sample(s)", session_id[:6], kind,
                 job_id, *size, len(cameras), len(work.pieces), samples)
        return job

    def find(self, session_id: str, job_id: str, kind: str) -> RenderJob | None:
        job = self.jobs.get(job_id)
        return job if job is not None and job.session == session_id and job.kind == kind else None

    def of_session(self, session_id: str, kind: str | None = None) -> list[RenderJob]:
        return [job for job in self.jobs.values() if job.session == session_id and kind in (None, job.kind)]

    def restore(self, session_id: str, records: Any) -> None:
        """A restarted session's jobs: each reads as failed (:data:`RESTART_REASON`)."""
        for record in records or ():
            with contextlib.suppress(KeyError, TypeError):
                job = RenderJob(str(record["id"]), session_id, str(record["kind"]), None)
                self.jobs[job.job_id] = job

    # ----------------------------------------------------------------- ended
    def cancel(self, job: RenderJob) -> None:
        """Cancel ``job`` if it is under way (its tiles dropped), else forget it and delete its output."""
        if job.work is not None and not job.work.finished:
            self._end(job, CANCELLED, "cancelled")
            return
        self._delete(job)

    def session_closed(self, session_id: str) -> None:
        """The session closed (or its scene changed): its jobs end and are forgotten."""
        for job in self.of_session(session_id):
            if job.work is not None and not job.work.finished:
                self._end(job, CANCELLED, "the session was closed or its scene changed")
            self._delete(job)

    def close(self) -> None:
        """The coordinator stops: every job ends, the folder goes."""
        self._worker.shutdown(wait=True, cancel_futures=True)
        for pixels in self._pixels.values():
            pixels.close()
        shutil.rmtree(self.folder, ignore_errors=True)

    def _end(self, job: RenderJob, state: str, reason: str | None) -> None:
        self.host.scheduler.end_job(job.job_id, time.monotonic(), state, reason)
        if job.work is not None and not job.work.finished:
            job.work.end(state, reason)
        pixels = self._pixels.pop(job.job_id, None)
        if pixels is not None:
            self._worker.submit(pixels.close)
        self.host.apply()
        if state != DONE:
            log.info("%s %s %s: %s", job.kind, job.job_id, state, reason)

    def _delete(self, job: RenderJob) -> None:
        self.jobs.pop(job.job_id, None)
        if job.path is not None:
            for path in (job.path, job.path.with_suffix(".part")):
                with contextlib.suppress(OSError):
                    path.unlink()

    def _forget_old(self, session_id: str) -> None:
        finished = [job for job in self.of_session(session_id) if job.work is None or job.work.finished]
        for job in sorted(finished, key=lambda j: j.created)[:max(0, len(self.of_session(session_id)) - KEPT_JOBS)]:
            self._delete(job)

    # ----------------------------------------------------------------- tiles
    def tile(self, frame: FrameJob, merged: list[tuple[Any, Codec, int, bytes]] | None = None) -> None:
        """A job tile came back (the scheduler published it): its pixels (sort-last: its depth
        tiles ``merged``, the one image of the piece) go to the worker thread."""
        job = self.jobs.get(frame.job or "")
        pixels = self._pixels.get(frame.job or "")
        tile = frame.tiles[0]
        if job is None or pixels is None or frame.item is None or tile.payload is None or tile.header is None:
            return
        _, codec, _, payload = merged[0] if merged else (tile.rect, tile.header.codec, 0, tile.payload)
        done: Future[list[int]] = self._worker.submit(pixels.add, frame.item, payload, codec)
        loop = asyncio.get_running_loop()

        def back_to_the_loop(future: Future[list[int]]) -> None:
            with contextlib.suppress(RuntimeError):   # the loop closed: the coordinator stopped
                loop.call_soon_threadsafe(self._added, job, future)

        done.add_done_callback(back_to_the_loop)

    def _added(self, job: RenderJob, done: Future[list[int]]) -> None:
        work = job.work
        if work is None or work.finished or done.cancelled():
            return
        if done.exception() is not None:
            self._end(job, ERROR, f"{type(done.exception()).__name__}: {done.exception()}"[:300])
            return
        for picture in done.result():
            self.host.scheduler.picture_taken(job.job_id, picture, time.monotonic())
        if work.pictures_done == len(work.spec.cameras):
            self._end(job, DONE, None)
        self.host.apply()

    # ----------------------------------------------------------------- figures
    def describe_session(self, session_id: str) -> list[dict[str, Any]]:
        """``/api/stats``' ``jobs``: the session's jobs (:meth:`RenderJob.describe`)."""
        return [job.describe() for job in self.of_session(session_id)]
