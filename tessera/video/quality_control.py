"""The H.264 stream's constant rate factor, held so the video's PSNR matches the tiles' (issue 37):
a viewer on video should see the picture a viewer on tiles (JPEG at the session's quality) sees, at
fewer bytes. Which CRF gives that depends on the scene, the camera and the frame size (on the
default scene CRF 28.5 matched the JPEG q60 tiles; Lucy needed 26), so it is measured as the
stream runs: the coordinator compares the decoded video and the tiles' JPEG with the raw tiles
(``server/video_quality.py``) and each pair goes through :func:`observe`.

The law, pure (PSNRs in, a CRF out; the state a frozen :class:`CrfLoop`):

- only frames encoded at the current CRF count (a measurement comes back after the frame's
  encoding, and a change may have come in between);
- a decision takes :data:`MIN_SAMPLES` measurements at the current CRF, then one every
  :data:`DECIDE_EVERY`, each over the last :data:`HISTORY` of them;
- the CRF holds while the mean surplus (video − tiles − :data:`TARGET_DB`) is within
  :data:`BAND_DB` of 0 or not surely outside it (by :data:`Z_BELOW` standard errors when the video
  is under the target, :data:`Z_ABOVE` over it: a video below the tiles is put right sooner than
  bytes are saved). Each change opens a new encoder (a keyframe), so a frame's scatter must not
  move it;
- else it steps by the surplus over the PSNR's slope per CRF unit (learnt from the means either
  side of a change of at least :data:`LEARN_MIN_STEP`), damped by :data:`GAIN`, at least one
  :data:`QUANTUM` and at most :data:`MAX_STEP`, within the bounds; a bound it heads for and
  stands at holds it.

It settles from any start within the bounds: a step of one quantum moves the PSNR by at most
``QUANTUM`` × 1 dB (the slopes measured are 0.1-0.9), less than the band's width, so some CRF on
the grid is inside the band and no two neighbours both overshoot it.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, replace

#: The CRF range the loop keeps to: below 18 x264 spends bytes on noise no one sees; above 36 the
#: picture blurs visibly.
CRF_RANGE = (18.0, 36.0)
#: The video aims this far above the tiles' PSNR (dB): the frames the loop does not measure (a
#: keyframe and the few after it) are below the rest, and the loop holds a CRF whose mean lies up to
#: the band and 1.5 standard errors under the aim. At 0.1 a camera of Lucy (1280x720, 20° a frame)
#: stayed 0.46 dB under the tiles; at 0.3, +0.18 to +0.20 dB over them at the worst camera of Lucy and
#: of the default scene, for 1.5-4 % more bytes (``bench.video_rd --loop``; issue 37).
TARGET_DB = 0.3
#: The mean surplus may sit this far either side of the target (dB) before the CRF moves.
BAND_DB = 0.15
#: Standard errors of the mean by which a surplus must be outside the band: below the target,
#: above it.
Z_BELOW = 1.5
Z_ABOVE = 2.5
#: The least scatter (dB, standard deviation of a measurement) assumed, however alike the last were.
NOISE_FLOOR_DB = 0.1
#: Measurements at a CRF before its first decision, between decisions, and the most a decision uses.
MIN_SAMPLES = 8
DECIDE_EVERY = 4
#: Measurements between decisions once one held the CRF (fewer chances for a frame's scatter).
HOLD_EVERY = 12
HISTORY = 24
#: What one CRF unit costs in PSNR at first (dB): measured offline at 1280x720 on orbits of the
#: default scene and Lucy, 0.40-0.55 dB between CRF 24 and 31 (the diorama 0.1-0.35).
SLOPE_DB = 0.45
#: The slopes a learnt one is kept within (dB per CRF unit).
SLOPE_RANGE_DB = (0.1, 1.0)
#: The smallest change (CRF units) whose either side teaches the slope: over a smaller one the
#: means' scatter outweighs the difference.
LEARN_MIN_STEP = 1.0
#: Share of the estimated step taken (under 1: a slope learnt too low does not overshoot).
GAIN = 0.8
#: The largest change in one step (CRF units).
MAX_STEP = 3.0
#: CRF values are multiples of this.
QUANTUM = 0.25


@dataclass(frozen=True)
class CrfLoop:
    """One stream's loop: the CRF in use (kept within ``lowest`` … ``highest``), the slope it goes
    by, the surpluses (dB) measured at this CRF since it was set (the last :data:`HISTORY`),
    whether the last decision held it (``settled``), and counts: changes made, measurements taken
    (finite pairs at the CRF in use), and measurements at this CRF."""

    crf: float
    lowest: float = CRF_RANGE[0]
    highest: float = CRF_RANGE[1]
    target_db: float = TARGET_DB
    slope_db: float = SLOPE_DB
    samples: tuple[float, ...] = ()
    since_change: int = 0
    settled: bool = False
    changes: int = 0
    measured: int = 0
    #: (CRF, mean surplus) just before the last change, until the slope learnt from it.
    before: tuple[float, float] | None = None
    #: The last change (CRF units, signed; 0: none yet) and the largest the next may be.
    last_step: float = 0.0
    max_step: float = MAX_STEP

    def __post_init__(self) -> None:
        if not self.lowest <= self.highest:
            raise ValueError(f"need lowest <= highest, got {self.lowest} and {self.highest}")
        object.__setattr__(self, "crf", min(max(float(self.crf), self.lowest), self.highest))

    @property
    def surplus_db(self) -> float | None:
        """The mean surplus (video − tiles − target, dB) measured at this CRF (None: none yet)."""
        return statistics.fmean(self.samples) if self.samples else None


def observe(loop: CrfLoop, video_db: float, tiles_db: float, crf: float) -> CrfLoop:
    """``loop`` after one frame's PSNR of the decoded video and of the tiles' JPEG, both against the
    raw tiles (dB), the frame encoded at ``crf``. A frame either codes exactly (an infinite PSNR)
    tells nothing, nor does one of another CRF than the loop's."""
    if not (math.isfinite(video_db) and math.isfinite(tiles_db)) or crf != loop.crf:
        return loop
    samples = (*loop.samples, video_db - tiles_db - loop.target_db)[-HISTORY:]
    since = loop.since_change + 1
    loop = replace(loop, samples=samples, since_change=since, measured=loop.measured + 1)
    if since < MIN_SAMPLES or (since - MIN_SAMPLES) % (HOLD_EVERY if loop.settled else DECIDE_EVERY):
        return loop
    mean = statistics.fmean(samples)
    loop = _learnt(loop, mean)
    error = max(statistics.pstdev(samples), NOISE_FLOOR_DB) / math.sqrt(max(1.0, len(samples) / DECIDE_EVERY))
    if abs(mean) <= BAND_DB + (Z_BELOW if mean < 0 else Z_ABOVE) * error:
        return replace(loop, settled=True)
    # a turn back halves the largest step (the target lies between), a step the same way doubles it
    reversed_ = loop.last_step * mean < 0
    max_step = max(QUANTUM, abs(loop.last_step) / 2) if reversed_ else min(MAX_STEP, 2 * loop.max_step)
    size = min(max_step, max(QUANTUM, round(abs(GAIN * mean / loop.slope_db) / QUANTUM) * QUANTUM))
    new = min(max(round((loop.crf + math.copysign(size, mean)) / QUANTUM) * QUANTUM, loop.lowest), loop.highest)
    if new == loop.crf:
        return replace(loop, settled=True)   # at the bound it heads for
    return replace(loop, crf=new, samples=(), since_change=0, settled=False, changes=loop.changes + 1,
                   before=(loop.crf, mean), last_step=new - loop.crf, max_step=max_step)


def _learnt(loop: CrfLoop, mean: float) -> CrfLoop:
    """``loop`` with its slope learnt from the mean before its last change and ``mean`` (the first
    decision's after it), when that change was large enough."""
    if loop.before is None:
        return loop
    crf, before = loop.before
    loop = replace(loop, before=None)
    if abs(loop.crf - crf) < LEARN_MIN_STEP:
        return loop
    low, high = SLOPE_RANGE_DB
    observed = (before - mean) / (loop.crf - crf)
    return replace(loop, slope_db=min(max(0.5 * loop.slope_db + 0.5 * observed, low), high))


def restarted(loop: CrfLoop) -> CrfLoop:
    """``loop`` for a source of other frames (a new size): its CRF and slope, no measurements."""
    return replace(loop, samples=(), since_change=0, settled=False, before=None)
