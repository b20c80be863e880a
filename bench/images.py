"""Frames the benchmarks and the tests compare: the PSNR of two images, and a viewer frame message's
tiles decoded into one image."""

from __future__ import annotations

import math

import numpy as np

from tessera.wire.codec import decode
from tessera.wire.protocol import unpack_frame

#: The PSNR a JSON report writes for identical images (JSON has no infinity), and for any higher one.
REPORTED_PSNR_CAP_DB = 100.0


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """Peak signal-to-noise ratio in dB of two uint8 images of one shape ((h, w, 3)), over every
    channel value; ``math.inf`` when they are equal.

    Equal images have a mean squared error of 0 and no finite PSNR. A finite stand-in would be
    reached by real differences (one level off in one value of a 1280x720 frame is 114 dB), so
    ``psnr(a, b) == math.inf`` means exactly equal, and ``psnr(a, b) >= bound`` holds for equal
    images whatever the bound. Reports written as JSON pass it through :func:`reported_psnr`."""
    mse = float(np.mean((image.astype(np.float64) - reference.astype(np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0 ** 2 / mse)


def reported_psnr(db: float) -> float:
    """A PSNR as a JSON report writes it: rounded to 0.01 dB, at most :data:`REPORTED_PSNR_CAP_DB`
    (so 100 stands for identical images)."""
    return round(min(db, REPORTED_PSNR_CAP_DB), 2)


def viewer_frame_image(message: bytes) -> np.ndarray:
    """The viewer frame ``message`` (a binary TFRM message, :func:`tessera.wire.protocol.pack_frame`)
    as one image: every tile decoded and pasted at its rect, (h, w, 3) uint8; black where no tile is."""
    frame = unpack_frame(message)
    width, height = frame.size
    image = np.zeros((height, width, 3), np.uint8)
    for entry, payload in frame.tiles:
        rect = entry.rect
        image[rect.y:rect.y1, rect.x:rect.x1] = decode(payload, entry.codec, rect.w, rect.h)
    return image
