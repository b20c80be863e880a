"""Progressive still (issue 20): once the camera rests, the still is refined by accumulating
frames rendered with sub-pixel jitter — Equalizer's idle anti-aliasing ("subpixel" compounds:
while the application is idle, frames are re-rendered with a jittered projection and averaged
until a set number of samples is reached). None of the seeds (``/work/shared/SEEDS.md``: 000-004)
describes it; this is what a rendering engineer would expect of it:

* **Jitter.** Sample ``k`` (0-based) of a still is rendered with the whole frame shifted by
  :func:`jitter`\\ (k) pixels, the Halton (2, 3) point ``k + 1`` moved to [-0.5, 0.5)² — a
  low-discrepancy sequence, so any prefix covers the pixel evenly. Sample 0 of a one-sample still
  is not shifted (that still is the interactive frame's picture, losslessly). Every tile of one
  sample has the same offset: it is a shift of the full-frame projection (:func:`jitter_matrix`),
  so tiles still join without seams.
* **Texture detail.** N samples in a pixel are as dense as √N × √N supersampling, whose textures
  are read √N times finer: each sample reads its textures with the LOD bias −½·log₂ N
  (:func:`lod_bias`; −2 at 16 samples, as a 4×4 supersampled frame). Without it the mean keeps the
  one-sample frame's mip level and textured scenes stop near 41 dB against the 4×4 supersampled
  frame (the milk truck at 8-32 samples), with it they reach 50-54 dB (``python -m bench.picture``).
* **Accumulation.** The samples' 8-bit pixels are summed as integers (:class:`Accumulator`) and the
  picture shown after ``n`` samples is their mean rounded half up: exact, the same wherever it is
  computed (the coordinator, ``--render-once``), whatever the order the tiles arrive in. The mean
  of sRGB-encoded values, as the MSAA resolve and the 4×4 supersampled reference average them.
* **State.** :class:`RefinementPlan` says how many samples a still wants; the scheduler asks for them
  one frame at a time and any change of the state cancels the refinement.

Pure: numpy arrays in, arrays out.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

#: Most samples a still may accumulate (the viewer frame header's sample count has 7 bits).
MAX_STILL_SAMPLES = 127
#: Samples of the still by default (``--still-samples``): the fewest (of 1, 2, 4, 8, 16, 32) whose
#: still reaches 45 dB against the 4×4 supersampled frame on the diorama, truck and engine scenes
#: (``python -m bench.picture --msaa 1 --still-samples 1,2,4,8,16,32``, 1280x720, llvmpipe: 8
#: samples 46.6 / 50.1 / 49.1 dB, 4 samples 40.8 / 43.7 / 43.4 dB, one sample 35.9 / 37.5 / 38.8 dB).
DEFAULT_STILL_SAMPLES = 8


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
    """How sample ``sample`` of a still of ``samples`` is drawn (None, a plain frame, for one sample)."""
    offset = jitter(sample, samples)
    return None if offset is None else Subsample(offset, lod_bias(samples))


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
    or tile by tile (:meth:`add` with a rect); :attr:`count` rises by :meth:`finish_sample`."""

    def __init__(self, size: tuple[int, int]) -> None:
        self.size = size
        self.sums = np.zeros((size[1], size[0], 3), np.uint16)
        self.count = 0

    def add(self, pixels: np.ndarray, x: int = 0, y: int = 0) -> None:
        """Add (h, w, 3) uint8 ``pixels`` of the current sample at (``x``, ``y``) px from the top left."""
        height, width = pixels.shape[:2]
        self.sums[y:y + height, x:x + width] += pixels

    def finish_sample(self) -> None:
        """The current sample is whole (every pixel added once)."""
        if self.count == MAX_STILL_SAMPLES:
            raise ValueError(f"a still holds at most {MAX_STILL_SAMPLES} samples")
        self.count += 1

    def mean(self, x: int = 0, y: int = 0, width: int | None = None, height: int | None = None) -> np.ndarray:
        """The mean of the samples so far, rounded half up, (h, w, 3) uint8, of the rect at
        (``x``, ``y``) of ``width`` × ``height`` px (default: the whole frame)."""
        if self.count == 0:
            raise ValueError("no sample accumulated yet")
        width = self.size[0] - x if width is None else width
        height = self.size[1] - y if height is None else height
        return mean_table(self.count)[self.sums[y:y + height, x:x + width]]


@functools.lru_cache(maxsize=8)
def mean_table(count: int) -> np.ndarray:
    """(255·count + 1,) uint8: a sum of ``count`` samples' 8-bit values → their mean rounded half up
    (a table look-up costs half of numpy's integer division on a 1280x720 frame)."""
    sums = np.arange(255 * count + 1, dtype=np.int64)
    return ((2 * sums + count) // (2 * count)).astype(np.uint8)


def accumulate(frames: list[np.ndarray]) -> np.ndarray:
    """The mean of whole (h, w, 3) uint8 ``frames`` as :class:`Accumulator` makes it."""
    height, width = frames[0].shape[:2]
    accumulator = Accumulator((width, height))
    for frame in frames:
        accumulator.add(frame)
        accumulator.finish_sample()
    return accumulator.mean()


class RefinementPlan:
    """How many samples a still wants (``samples``, 1…:data:`MAX_STILL_SAMPLES`) and how many of the
    current still's have started (``started``) — the render-on-demand side of the progressive still."""

    def __init__(self, samples: int) -> None:
        if not 1 <= samples <= MAX_STILL_SAMPLES:
            raise ValueError(f"still samples must be 1..{MAX_STILL_SAMPLES}, got {samples}")
        self.samples = samples
        self.started = 0

    @property
    def owed(self) -> bool:
        """A sample of the current still has yet to start."""
        return self.started < self.samples

    def restart(self) -> None:
        """The state changed: the next still starts from sample 0."""
        self.started = 0

    def start(self) -> int:
        """The next sample's index (0-based); ValueError when every sample has started."""
        if not self.owed:
            raise ValueError(f"all {self.samples} samples of the still have started")
        self.started += 1
        return self.started - 1
