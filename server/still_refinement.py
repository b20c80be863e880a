"""The progressive still on the coordinator (issues 20, 37): each sample frame of a session's still
is decoded and added to the session's :class:`tessera.scheduling.refinement.Accumulator` on one
worker thread shared by the sessions (off the event loop, so input is read meanwhile); the running
mean is encoded again as the frame's tiles when it is shown. The accumulator estimates the mean's
error at its plan's checks and says when the still converged (an adaptive still's estimate reached
its target, or the most samples are in); the service then publishes it as the still frame, when
nothing changed since, and tells the scheduler to stop asking for samples. Samples that were
already on their way are not added: the still is the mean of the samples up to convergence, the
same as ``--render-once`` makes.

What is shown of a still: the converged mean, exact, in the still codec (lossless
PNG by default); before it, refinement frames from :data:`FIRST_SHOWN` samples on, encoded as JPEG
(:data:`REFINEMENT_QUALITY`, 4:4:4: 3 ms a 1280x720 frame where PNG takes 13-26 ms): the first of
them always (viewers see the still under way), the others only when no later sample waits on the
thread already (a newer picture is about to be made). The mean of
fewer samples would show a worse picture than the interactive frame before it (the mean of 4
jittered samples is further from the 4×4 supersampled frame than llvmpipe's filtered two-sample
frame on two of three scenes; of 5 it is nearer on all three), and each costs the coordinator's CPU beside
the nodes rendering the next sample.

Why here and not in the viewer: the converged still must also be served as one image
(``GET /api/frame.png?still=true``), and old viewers that draw what they get show the improving
picture; accumulating in the page instead would send every sample's lossless tiles and spare the
coordinator only the encoding.
"""

from __future__ import annotations

import time
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from typing import Any

from server.frame_store import PublishedFrame
from tessera.geometry import Rect
from tessera.scheduling.refinement import Accumulator, StillPlan
from tessera.wire.codec import Codec, decode, encode

#: A frame's tiles as published: (rect, codec, node slot, payload).
Tiles = list[tuple[Rect, Codec, int, bytes]]
#: The fewest samples a refinement frame shown holds: the first mean of a default still of 8 nearer
#: the 4×4 supersampled frame than the interactive frame on llvmpipe (two samples, filtered): diorama
#: / truck / engine 43.9 / 47.8 / 46.7 dB after 5 samples against 41.7 / 43.7 / 44.0; after 4 samples
#: 40.8 / 44.4 / 43.4 (1280x720, 2 orbit cameras, ``python -m bench.picture``'s scenes and reference).
FIRST_SHOWN = 5
#: JPEG quality of refinement frames before the converged still (4:4:4 from 90).
REFINEMENT_QUALITY = 95
#: An estimate reported for a mean identical to its first half's (no finite PSNR), dB.
ESTIMATE_CAP_DB = 100.0


def reported_estimate(estimate_db: float | None) -> float | None:
    """An estimated PSNR as the stats and headers say it: rounded to 0.01 dB, at most :data:`ESTIMATE_CAP_DB`."""
    return None if estimate_db is None else round(min(estimate_db, ESTIMATE_CAP_DB), 2)


def still_figures(latest: PublishedFrame | None, plan: StillPlan) -> dict[str, Any]:
    """``/api/stats``' ``still_samples``: the samples the newest frame holds (``done``; 0: not a
    still's), the most the still takes (``wanted``), whether it is ``adaptive`` and its
    ``target_db``, and the newest frame's estimated PSNR against the converged image
    (``estimated_psnr_db``; None: not estimated)."""
    return {"done": latest.samples if latest else 0, "wanted": plan.most, "adaptive": plan.adaptive,
            "target_db": plan.target_db if plan.adaptive else None,
            "estimated_psnr_db": reported_estimate(latest.estimate_db if latest else None)}


@dataclass(frozen=True, slots=True)
class Refined:
    """What a sample made: the frame's ``tiles`` to show, the ``samples`` they hold, whether they
    are the ``converged`` still, and the newest estimate of the mean's PSNR against the converged
    image (``estimate_db``, dB; None before the first check)."""

    tiles: Tiles
    samples: int
    converged: bool
    estimate_db: float | None


class StillRefiner:
    """One session's accumulated still. :meth:`submit` hands a sample's tiles to ``executor`` (one
    thread: samples are added in order) and gives a future of what to show (None: nothing — a
    sample out of turn or after convergence, not added, or a refinement not shown); ``pending``
    counts those whose result the event loop has not taken yet (:meth:`taken`)."""

    def __init__(self, executor: Executor) -> None:
        self._executor = executor
        self._accumulator: Accumulator | None = None
        #: The newest sample submitted (read on the worker thread: a later one waits).
        self._submitted = -1
        self.pending = 0
        #: CPU time of the worker thread spent on this session's samples, ms.
        self.cpu_ms = 0.0

    def submit(self, sample: int, plan: StillPlan, size: tuple[int, int], tiles: Tiles, codec: Codec,
               quality: int, refinements: bool = True) -> Future[Refined | None]:
        """Add sample ``sample`` (0: a new still) of a still sampled as ``plan`` says, a ``size``
        frame, its ``tiles``; the converged mean's tiles come encoded in ``codec`` (``quality``:
        JPEG only), a refinement's as JPEG (none without ``refinements``: a point cloud's still of
        every point after its first still, which stays shown until this one converged)."""
        self.pending += 1
        self._submitted = sample
        return self._executor.submit(self._add, sample, plan, size, tiles, codec, quality, refinements)

    def taken(self) -> None:
        """The event loop took a sample's result."""
        self.pending -= 1

    def _add(self, sample: int, plan: StillPlan, size: tuple[int, int], tiles: Tiles, codec: Codec,
             quality: int, refinements: bool) -> Refined | None:
        started = time.thread_time()
        try:
            if sample == 0:
                self._accumulator = Accumulator(size, plan)
            accumulator = self._accumulator
            if (accumulator is None or accumulator.size != size or accumulator.plan != plan
                    or accumulator.count != sample or accumulator.converged):
                return None
            for rect, tile_codec, _, payload in tiles:
                accumulator.add(decode(payload, tile_codec, rect.w, rect.h), rect.x, rect.y)
            accumulator.finish_sample()
            if not accumulator.converged:
                if (not refinements or accumulator.count < FIRST_SHOWN
                        or (accumulator.count > FIRST_SHOWN and self._submitted > sample)):
                    return None
                codec, quality = Codec.JPEG, quality if codec is Codec.JPEG else REFINEMENT_QUALITY
            shown = [(rect, codec, slot, encode(accumulator.mean(rect.x, rect.y, rect.w, rect.h), codec, quality))
                     for rect, _, slot, _ in tiles]
            return Refined(shown, accumulator.count, accumulator.converged, accumulator.estimate_db)
        finally:
            self.cpu_ms += (time.thread_time() - started) * 1e3
