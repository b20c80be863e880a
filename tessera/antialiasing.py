"""The resolve filters of one-sample and paired frames (issue 20): how a frame drawn with one or two
samples per pixel comes closer to the pixel's area — what the 4×4 supersampled reference averages —
than its samples alone.

A frame drawn at one sample per pixel holds each pixel's centre; the reference (and a multisampled
pixel) holds the mean over the pixel's square. :func:`resolve_filter` estimates that mean from the
centre samples of the pixel and its neighbours: the separable kernel [1, 6, 1] / 8 along x and along
y (weights 36/64 on the pixel, 6/64 on each side neighbour, 1/64 on each corner), integers, rounded
half up. It is close to the least-squares 3×3 kernel from the one-sample frames of the benchmark's
scenes to their 4×4 supersampled references (centre 0.56, sides 0.106, corners 0.004), and as good:
+3.4 to +3.8 dB on the scenes whose error is at edges, +1.7 dB on the milk truck, whose error is in
its textures (:data:`FILTERED_LOD_BIAS`) (``python -m bench.picture``). A linear filter only spreads
what the samples saw: geometry thinner than a pixel stays as aliased as it was drawn, which a second
sample halves. :func:`resolve_pair_filter` resolves a frame drawn twice as wide, two samples a pixel
¼ pixel left and right of its centre (``--msaa auto`` on llvmpipe): the pair summed, [1, 14, 1] / 16
along x (the pair already spans the pixel's width; [1, 6, 1] gave the diorama 0.4 dB less) and
[1, 6, 1] / 8 along y: +1.5 to +2.2 dB over the one-sample filter on the seven scenes, the diorama
41.7 dB where one sample reaches 39.6.

Tiles stay seamless: a pixel's result depends on its 3×3 neighbourhood only, so a tile is drawn with
a guard band of :data:`GUARD` pixel around it (:func:`guarded`), and outside the frame the nearest
frame pixel stands in (clamp to edge) — the same neighbourhood whichever tile a pixel lies in.
Pure: numpy arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np

from tessera.geometry import Rect

#: Pixels each side of a tile that the filter reads.
GUARD = 1
#: Texture LOD bias of filtered frames: textures read one level finer, as a still of 4 samples reads
#: them (the filter blurs a little; finer texels make up for it: the milk truck +3.0 dB against the
#: 4×4 supersampled frame, the duck +1.3 dB). Finer still gains little more (-1.5: +0.5 and +0.2 dB)
#: and one sample per pixel would shimmer in motion.
FILTERED_LOD_BIAS = -1.0


def guarded(rect: Rect, size: tuple[int, int]) -> Rect:
    """``rect`` grown by :data:`GUARD` pixels on each side, clipped to the ``size`` = (w, h) frame."""
    x, y = max(rect.x - GUARD, 0), max(rect.y - GUARD, 0)
    return Rect(x, y, min(rect.x1 + GUARD, size[0]) - x, min(rect.y1 + GUARD, size[1]) - y)


def resolve_filter(pixels: np.ndarray, rect: Rect, drawn: Rect) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``rect`` of the frame filtered, from ``pixels`` (drawn.h, drawn.w, 3)
    uint8, the frame's ``drawn`` = :func:`guarded` (``rect``) region; where the guard band was
    clipped by the frame's edge, the edge pixels stand in."""
    if pixels.shape[:2] != (drawn.h, drawn.w):
        raise ValueError(f"pixels are {pixels.shape[1]}x{pixels.shape[0]}, the drawn region {drawn.w}x{drawn.h}")
    return _separable(pixels.astype(np.uint16), rect, drawn, 6, 6, 6)


def resolve_pair_filter(pixels: np.ndarray, rect: Rect, drawn: Rect) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``rect`` of the frame drawn with two samples per pixel, ¼ pixel
    left and right of its centre, from ``pixels`` (drawn.h, 2·drawn.w, 3) uint8: the ``drawn`` =
    :func:`guarded` (``rect``) region of a frame drawn twice as wide, column 2i and 2i + 1 the
    samples of pixel i. Each pixel's pair is summed, then filtered by [1, 14, 1] / 16 along x (the
    pair already covers the pixel's width) and [1, 6, 1] / 8 along y, rounded half up; where the
    guard band was clipped by the frame's edge, the edge pixels stand in."""
    if pixels.shape[:2] != (drawn.h, 2 * drawn.w):
        raise ValueError(f"pixels are {pixels.shape[1]}x{pixels.shape[0]}, the drawn region twice as wide "
                         f"{2 * drawn.w}x{drawn.h}")
    pairs = pixels[:, 0::2].astype(np.uint16)
    pairs += pixels[:, 1::2]
    return _separable(pairs, rect, drawn, 14, 6, 8)


def _separable(values: np.ndarray, rect: Rect, drawn: Rect, centre_x: int, centre_y: int, shift: int) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``values`` (drawn.h, drawn.w, 3) uint16 of the ``drawn`` region
    filtered by [1, ``centre_x``, 1] along x and [1, ``centre_y``, 1] along y (edge pixels standing in
    beyond a clipped guard band), divided by 2**``shift`` rounded half up; the sums stay under 2**16."""
    pad = ((GUARD - (rect.y - drawn.y), GUARD - (drawn.y1 - rect.y1)),
           (GUARD - (rect.x - drawn.x), GUARD - (drawn.x1 - rect.x1)), (0, 0))
    if any(before < 0 or after < 0 for before, after in pad):
        raise ValueError(f"drawn region {drawn.as_list()} is not rect {rect.as_list()} with its guard band")
    wide = np.pad(values, pad, mode="edge")
    rows = wide[:, 1:-1] * np.uint16(centre_x)
    rows += wide[:, :-2]
    rows += wide[:, 2:]
    out = rows[1:-1] * np.uint16(centre_y)
    out += rows[:-2]
    out += rows[2:]
    out += np.uint16(1 << (shift - 1))
    out >>= shift
    return out.astype(np.uint8)
