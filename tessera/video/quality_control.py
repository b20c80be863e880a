"""The H.264 stream's constant rate factor, held so the video's PSNR matches the tiles' (issue 37):
a viewer on video should see the picture a viewer on tiles (JPEG at the session's quality) sees, at
fewer bytes. Which CRF gives that depends on the scene, the camera and the frame size (on the
default scene CRF 28.5 matched the JPEG q60 tiles; Lucy needed 26), so it is measured as the
stream runs: every few frames the coordinator compares the decoded video and the tiles' JPEG with
the raw tiles (``server/video_quality.py``), and each :data:`WINDOW` such pairs steer the CRF.

The step is the window's mean shortfall over the PSNR's slope per CRF unit (:data:`SLOPE_DB`,
learnt from the windows either side of each change, within :data:`SLOPE_RANGE_DB`), damped by
:data:`GAIN` and at most :data:`MAX_STEP`; within :data:`BAND_DB` of the target nothing changes
(each change opens a new encoder, and so costs a keyframe). Pure: PSNRs in, a CRF out.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field

#: The CRF range the loop keeps to: below 18 x264 spends bytes on noise no one sees; above 36 the
#: picture blurs visibly.
CRF_RANGE = (18.0, 36.0)
#: Measurements (pairs of PSNRs) a decision takes.
WINDOW = 4
#: The video may sit this far either side of the tiles' PSNR (dB) before the CRF moves.
BAND_DB = 0.15
#: What one CRF unit costs in PSNR at first (dB): measured offline at 1280x720 on orbits of the
#: default scene and Lucy, 0.40-0.55 dB between CRF 24 and 31 (the diorama 0.1-0.35).
SLOPE_DB = 0.45
#: The slopes a learnt one is kept within (dB per CRF unit).
SLOPE_RANGE_DB = (0.1, 1.0)
#: Share of the estimated step taken (under 1: a slope learnt too low does not overshoot).
GAIN = 0.8
#: The largest change in one step (CRF units).
MAX_STEP = 3.0
#: CRF values are multiples of this.
QUANTUM = 0.25


@dataclass
class CrfControl:
    """The CRF of one stream, starting at ``crf`` and kept within ``lowest`` … ``highest``;
    ``target_offset_db``: the video aims this far above the tiles' PSNR."""

    crf: float
    lowest: float = CRF_RANGE[0]
    highest: float = CRF_RANGE[1]
    target_offset_db: float = 0.0
    slope_db: float = SLOPE_DB
    #: Changes made so far.
    changes: int = 0
    #: Measurements taken so far (finite pairs).
    measured: int = 0
    _window: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=WINDOW))
    #: (CRF, mean video − tiles dB) of the last window before the last change.
    _before: tuple[float, float] | None = None
    #: The last full window's mean PSNRs (video, tiles), dB.
    last_window: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not self.lowest <= self.highest:
            raise ValueError(f"need lowest <= highest, got {self.lowest} and {self.highest}")
        self.crf = min(max(float(self.crf), self.lowest), self.highest)

    def observe(self, video_db: float, tiles_db: float) -> float | None:
        """One frame's PSNR of the decoded video and of the tiles' JPEG, both against the raw tiles
        (dB; an infinite one, a frame either codes exactly, tells nothing and is left out). The new
        CRF when this measurement completes a window that moves it, else None."""
        if not (math.isfinite(video_db) and math.isfinite(tiles_db)):
            return None
        self.measured += 1
        self._window.append((video_db, tiles_db))
        if len(self._window) < WINDOW:
            return None
        video = statistics.fmean(v for v, _ in self._window)
        tiles = statistics.fmean(t for _, t in self._window)
        self._window.clear()
        self.last_window = (video, tiles)
        surplus = video - tiles - self.target_offset_db
        self._learn(surplus)
        if abs(surplus) <= BAND_DB:
            return None
        step = max(-MAX_STEP, min(MAX_STEP, GAIN * surplus / self.slope_db))
        crf = min(max(round((self.crf + step) / QUANTUM) * QUANTUM, self.lowest), self.highest)
        self._before = (self.crf, surplus)
        if crf == self.crf:
            return None
        self.crf = crf
        self.changes += 1
        return crf

    def _learn(self, surplus: float) -> None:
        """The slope from the window before the last change and this one (the first after it)."""
        if self._before is None:
            return
        crf, before = self._before
        self._before = None
        if self.crf != crf:
            observed = (before - surplus) / (self.crf - crf)
            low, high = SLOPE_RANGE_DB
            self.slope_db = min(max(0.5 * self.slope_db + 0.5 * observed, low), high)
