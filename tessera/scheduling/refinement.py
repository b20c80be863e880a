"""Progressive still (issues 20, 37): once the camera rests, the still is refined by accumulating
frames rendered with sub-pixel jitter — Equalizer's idle anti-aliasing ("subpixel" compounds:
while the application is idle, frames are re-rendered with a jittered projection and averaged).
None of the seeds (``/work/shared/SEEDS.md``: 000-004) describes it; this is what a rendering
engineer would expect of it:

* **Jitter.** Sample ``k`` (0-based) of a still is rendered with the whole frame shifted by
  :func:`jitter`\\ (k) pixels, the Halton (2, 3) point ``k + 1`` moved to [-0.5, 0.5)² — a
  low-discrepancy sequence, so any prefix covers the pixel evenly. Sample 0 of a one-sample still
  is not shifted (that still is the interactive frame's picture, losslessly). Every tile of one
  sample has the same offset: it is a shift of the full-frame projection (:func:`jitter_matrix`),
  so tiles still join without seams.
* **Texture detail.** N samples in a pixel are as dense as √N × √N supersampling, whose textures
  are read √N times finer: a still of a fixed N samples reads its textures with the LOD bias
  −½·log₂ N (:func:`lod_bias`; −2 at 16 samples, as a 4×4 supersampled frame). An adaptive still,
  whose count is not known ahead, reads them at :data:`ADAPTIVE_LOD_BIAS`, the 4×4 supersampled
  reference's: what its mean converges to is then that reference's texture detail (measured: see
  the design notes).
* **Grids.** Where the interactive frame draws a grid of samples per pixel (small frames on a
  software rasterizer, :mod:`tessera.antialiasing`), each sample of the still is that grid shifted
  within its cells (:func:`grid_subsample`) and averaged: the still refines the frame the viewer
  saw, every sample worth the grid's count.
* **Accumulation.** The samples' 8-bit pixels are summed as integers (:class:`Accumulator`) and the
  picture shown after ``n`` samples is their mean rounded half up: exact, the same wherever it is
  computed (the coordinator, ``--render-once``), whatever the order the tiles arrive in. The mean
  of sRGB-encoded values, as the MSAA resolve and the 4×4 supersampled reference average them.
* **Convergence (issue 37).** An adaptive still (:class:`StillPlan` with ``samples`` =
  :data:`ADAPTIVE`) stops when it no longer changes the picture: at the counts of :data:`CHECKS`
  the accumulator estimates the error of its mean against the converged image as the RMS
  difference between the mean of all ``n`` samples and of the first ``n // 2``
  (:meth:`Accumulator.estimate_db`, exact integer arithmetic on the sums, so every machine decides
  alike), and the still is done once that estimate, in dB PSNR, reaches ``target_db``, or at
  ``max_samples``. The two halves of a Halton prefix each cover the pixel evenly and fill each
  other's gaps, so their difference overstates what the mean still lacks — at the counts of
  :data:`CHECKS`, not at others (measured on ``bench.picture``'s scenes: see the design notes). A
  fixed count is estimated too, at the checks it reaches and at its last sample, for the figures.
* **State.** :class:`RefinementPlan` says which samples a still wants; the scheduler asks for them
  one frame at a time, the coordinator says when an adaptive still converged, and any change of
  the state cancels the refinement.

Pure: numpy arrays in, arrays out.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Most samples a still may accumulate (the viewer frame header's sample count has 7 bits).
MAX_STILL_SAMPLES = 127
#: ``--still-samples auto``: the still accumulates samples until it converges (:class:`StillPlan`).
ADAPTIVE = 0
#: Samples of the still by default (``--still-samples``): adaptive.
DEFAULT_STILL_SAMPLES = ADAPTIVE
#: Most samples an adaptive still takes by default (``--still-samples-max``).
DEFAULT_MAX_STILL_SAMPLES = 64
#: The estimated PSNR against the converged image (dB) at which an adaptive still stops by
#: default (``--still-target-db``): the 4×4 supersampled reference is itself 46.5-47.4 dB from an
#: 8×8 supersampled one on the diorama and the truck at 640x360 (random cameras), so a still must be
#: nearer its converged image than 45 dB for the 4×4 reference to see 45 dB.
DEFAULT_STILL_TARGET_DB = 48.0
#: Texture LOD bias of an adaptive still's samples: the 4×4 supersampled reference's (16 samples).
ADAPTIVE_LOD_BIAS = -2.0
#: Sample counts at which an adaptive still estimates its error (:meth:`Accumulator.estimate_db`);
#: its ``max_samples`` is one too. Each compares the mean with the first half's, whose sums are
#: kept from then until the check (at most two such copies at a time).
CHECKS = (8, 16, 24, 32, 48, 64, 96)


def radical_inverse(index: int, base: int) -> float:
    """The van der Corput radical inverse of ``index`` ≥ 0 in ``base``: its digits mirrored about
    the radix point, in [0, 1)."""
    if index < 0 or base < 2:
        raise ValueError(f"index must be >= 0 and base >= 2, got {index}, {base}")
    value, scale = 0.0, 1.0 / base
    while index:
        index, digit = divmod(index, base)
        value += digit * scale
        scale /= base
    return value


def jitter(sample: int, samples: int) -> tuple[float, float] | None:
    """The sub-pixel offset (dx, dy) in pixels, x right and y down, in [-0.5, 0.5)², of sample
    ``sample`` (0-based) of a still of ``samples``; None (no shift) for a one-sample still."""
    if not 0 <= sample < samples:
        raise ValueError(f"sample {sample} is not one of a still of {samples}")
    if samples == 1:
        return None
    return radical_inverse(sample + 1, 2) - 0.5, radical_inverse(sample + 1, 3) - 0.5


def lod_bias(samples: int) -> float:
    """The texture LOD bias of a still of ``samples`` (−½·log₂ samples; 0 for one sample)."""
    return -0.5 * math.log2(samples)


@dataclass(frozen=True, slots=True)
class Subsample:
    """How one sample of a still is drawn: the frame shifted by ``offset`` (dx, dy) px (x right,
    y down; None: not shifted), textures read with ``lod_bias``."""

    offset: tuple[float, float] | None = None
    lod_bias: float = 0.0

    @classmethod
    def of(cls, offset: tuple[float, float] | None, bias: float | None) -> Subsample | None:
        """The subsample a render message asks for (None: a plain frame)."""
        return None if offset is None and not bias else cls(offset, bias or 0.0)


def subsample(sample: int, samples: int) -> Subsample | None:
    """How sample ``sample`` of a still of a fixed ``samples`` is drawn (None, a plain frame, for one sample)."""
    offset = jitter(sample, samples)
    return None if offset is None else Subsample(offset, lod_bias(samples))


@dataclass(frozen=True, slots=True)
class StillPlan:
    """How a still is sampled: ``samples`` frames (a fixed count), or, with ``samples`` =
    :data:`ADAPTIVE`, until the estimated PSNR of the mean against the converged image reaches
    ``target_db`` at one of :meth:`checks`, at most ``max_samples``."""

    samples: int = 1
    max_samples: int = DEFAULT_MAX_STILL_SAMPLES
    target_db: float = DEFAULT_STILL_TARGET_DB

    def __post_init__(self) -> None:
        if not (self.samples == ADAPTIVE or 1 <= self.samples <= MAX_STILL_SAMPLES):
            raise ValueError(f"still samples must be 1..{MAX_STILL_SAMPLES} or adaptive, got {self.samples}")
        if not 2 <= self.max_samples <= MAX_STILL_SAMPLES:
            raise ValueError(f"an adaptive still's most samples must be 2..{MAX_STILL_SAMPLES}, got {self.max_samples}")
        if not 0.0 < self.target_db < 100.0:
            raise ValueError(f"the still's target must be 0..100 dB, got {self.target_db}")

    @property
    def adaptive(self) -> bool:
        return self.samples == ADAPTIVE

    @property
    def most(self) -> int:
        """The most samples the still takes."""
        return self.max_samples if self.adaptive else self.samples

    def subsample(self, sample: int) -> Subsample | None:
        """How sample ``sample`` (0-based) is drawn (None: a plain frame, for a one-sample still)."""
        if not self.adaptive:
            return subsample(sample, self.samples)
        offset = jitter(sample, self.max_samples)
        assert offset is not None
        return Subsample(offset, ADAPTIVE_LOD_BIAS)

    def checks(self) -> tuple[int, ...]:
        """The counts at which the error is estimated: those of :data:`CHECKS` below :attr:`most`,
        and :attr:`most` (none for a one-sample still)."""
        most = self.most
        return () if most < 2 else (*(n for n in CHECKS if n < most), most)

    def done(self, count: int, estimate_db: float | None) -> bool:
        """A still of ``count`` samples whose error was just estimated at ``estimate_db`` (None: not
        estimated at this count) is the converged still."""
        if count >= self.most:
            return True
        return self.adaptive and estimate_db is not None and estimate_db >= self.target_db


#: A still of one frame, not shifted (an interactive frame's plan).
ONE_FRAME = StillPlan(1)


def grid_subsample(sample: Subsample, grid: tuple[int, int]) -> Subsample:
    """``sample`` of a still drawn with a ``grid`` = (kx, ky) of samples per pixel (the interactive
    frame's anti-aliasing at that size): its offset scaled to one of the grid's cells, so every
    cell is refined by the same low-discrepancy sequence, and its LOD bias less what the grid's
    finer spacing already brings (log₂ of its smaller side), so textures are read as finely as
    ``sample`` says."""
    kx, ky = grid
    if grid == (1, 1):
        return sample
    offset = None if sample.offset is None else (sample.offset[0] / kx, sample.offset[1] / ky)
    return Subsample(offset, sample.lod_bias + math.log2(min(kx, ky)))


def jitter_matrix(offset: tuple[float, float] | None, size: tuple[int, int]) -> np.ndarray:
    """(4, 4) float64 clip-space matrix that moves the ``size`` = (w, h) image by ``offset`` pixels
    (x right, y down; None: the identity). Applied after the projection: x_ndc += 2 dx / w,
    y_ndc -= 2 dy / h (NDC y points up)."""
    matrix = np.identity(4)
    if offset is not None:
        matrix[0, 3] = 2.0 * offset[0] / size[0]
        matrix[1, 3] = -2.0 * offset[1] / size[1]
    return matrix


class Accumulator:
    """The running sum of a still's samples: (h, w, 3) uint16 for a ``size`` = (w, h) frame (at
    most :data:`MAX_STILL_SAMPLES` × 255 = 32385), and how many samples it holds. Samples come whole
    or tile by tile (:meth:`add` with a rect); :attr:`count` rises by :meth:`finish_sample`. With a
    ``plan``, the error is estimated at its :meth:`StillPlan.checks` (:attr:`estimate_db`) and
    :attr:`converged` says when the still is done."""

    def __init__(self, size: tuple[int, int], plan: StillPlan | None = None) -> None:
        self.size = size
        self.sums = np.zeros((size[1], size[0], 3), np.uint16)
        self.count = 0
        self.plan = plan
        checks = plan.checks() if plan is not None else ()
        self._checks = set(checks)
        #: The first half's sums each check compares with, by count (kept from then until the check).
        self._halves: dict[int, np.ndarray | None] = {n // 2: None for n in checks}
        #: The newest estimate: the mean's PSNR against the converged image (dB), and at which count.
        self.estimate_db: float | None = None
        self.estimated_at = 0
        self.converged = False

    def add(self, pixels: np.ndarray, x: int = 0, y: int = 0) -> None:
        """Add (h, w, 3) uint8 ``pixels`` of the current sample at (``x``, ``y``) px from the top left."""
        height, width = pixels.shape[:2]
        self.sums[y:y + height, x:x + width] += pixels

    def finish_sample(self) -> None:
        """The current sample is whole (every pixel added once): the count rises, and at a check
        of the plan the error is estimated and :attr:`converged` decided."""
        if self.count == MAX_STILL_SAMPLES:
            raise ValueError(f"a still holds at most {MAX_STILL_SAMPLES} samples")
        self.count += 1
        if self.count in self._halves:
            self._halves[self.count] = self.sums.copy()
        if self.count in self._checks:
            self.estimate_db = self.estimate_against(self.count // 2)
            self.estimated_at = self.count
            self._halves.pop(self.count // 2, None)
        if self.plan is not None:
            self.converged = self.plan.done(self.count, self.estimate_db if self.estimated_at == self.count else None)

    def estimate_against(self, half: int) -> float:
        """The estimated PSNR (dB; ``math.inf`` when equal) of the mean of all samples against the
        converged image: the RMS difference, over every pixel and channel, of the mean of all
        :attr:`count` samples and of the first ``half`` (whose sums were kept), in integers
        (``half``·S − count·S_half, summed in int64 by row blocks): exact, so every machine gets
        the same figure from the same samples."""
        kept = self._halves.get(half)
        if kept is None or not 0 < half < self.count:
            raise ValueError(f"the sums of the first {half} samples were not kept")
        total = 0
        rows = max(1, (1 << 19) // (self.size[0] * 3))   # a block's sum of squares stays far inside int64
        for top in range(0, self.size[1], rows):
            difference = self.sums[top:top + rows].astype(np.int64) * half
            difference -= kept[top:top + rows].astype(np.int64) * self.count
            total += int(np.einsum("ijk,ijk->", difference, difference))
        if total == 0:
            return math.inf
        mse = total / ((half * self.count) ** 2 * self.sums.size)
        return 10.0 * math.log10(255.0 ** 2 / mse)

    def mean(self, x: int = 0, y: int = 0, width: int | None = None, height: int | None = None) -> np.ndarray:
        """The mean of the samples so far, rounded half up, (h, w, 3) uint8, of the rect at
        (``x``, ``y``) of ``width`` × ``height`` px (default: the whole frame)."""
        if self.count == 0:
            raise ValueError("no sample accumulated yet")
        width = self.size[0] - x if width is None else width
        height = self.size[1] - y if height is None else height
        return mean_table(self.count)[self.sums[y:y + height, x:x + width]]


@functools.lru_cache(maxsize=16)
def mean_table(count: int) -> np.ndarray:
    """(255·count + 1,) uint8: a sum of ``count`` samples' 8-bit values → their mean rounded half up
    (a table look-up costs half of numpy's integer division on a 1280x720 frame)."""
    sums = np.arange(255 * count + 1, dtype=np.int64)
    return ((2 * sums + count) // (2 * count)).astype(np.uint8)


def accumulate_still(render: Callable[[Subsample | None], np.ndarray], size: tuple[int, int],
                     plan: StillPlan) -> Accumulator:
    """The still of ``plan`` as the coordinator accumulates it: ``render`` (subsample → the whole
    (h, w, 3) uint8 frame of ``size`` = (w, h) drawn so) called for sample after sample until the
    accumulator says it converged."""
    accumulator = Accumulator(size, plan)
    while not accumulator.converged:
        accumulator.add(render(plan.subsample(accumulator.count)))
        accumulator.finish_sample()
    return accumulator


def accumulate(frames: list[np.ndarray]) -> np.ndarray:
    """The mean of whole (h, w, 3) uint8 ``frames`` as :class:`Accumulator` makes it."""
    height, width = frames[0].shape[:2]
    accumulator = Accumulator((width, height))
    for frame in frames:
        accumulator.add(frame)
        accumulator.finish_sample()
    return accumulator.mean()


class RefinementPlan:
    """Which samples a still wants (``plan``: a :class:`StillPlan`, or a fixed count) and how many
    of the current still's have started (``started``) — the render-on-demand side of the
    progressive still. An adaptive still is done when the coordinator says it converged
    (:meth:`finish`) or once its most samples have started."""

    def __init__(self, plan: StillPlan | int) -> None:
        self.plan = plan if isinstance(plan, StillPlan) else StillPlan(plan)
        self.started = 0
        self.finished = False

    @property
    def samples(self) -> int:
        """The most samples the still takes."""
        return self.plan.most

    @property
    def owed(self) -> bool:
        """A sample of the current still has yet to start."""
        return not self.finished and self.started < self.plan.most

    def restart(self) -> None:
        """The state changed: the next still starts from sample 0."""
        self.started = 0
        self.finished = False

    def start(self) -> int:
        """The next sample's index (0-based); ValueError when no sample is owed."""
        if not self.owed:
            raise ValueError(f"the still's samples have all started or it converged ({self.started} started)")
        self.started += 1
        return self.started - 1

    def finish(self) -> None:
        """The still converged: no more samples are owed until the next :meth:`restart`."""
        self.finished = True
