"""A published frame's tiles as the video encoder's source picture (issue 21): planar YUV 4:2:0,
full range, BT.601 — the colour space JPEG (JFIF) tiles already hold, so JPEG tiles are decoded
without colour conversion (libjpeg's YCbCr output) and the chroma is decimated; tiles of other
codecs (PNG, raw, merged depth frames) are decoded to RGB and converted. The picture is padded
to even sides (4:2:0 needs them): the encoder codes the padded size, the message says the frame's.
"""

from __future__ import annotations

import io
from collections.abc import Iterable

import numpy as np
from PIL import Image

from tessera.geometry import Rect
from tessera.wire.codec import Codec, decode

#: RGB → full-range BT.601 YCbCr (JFIF), rows Y, Cb, Cr; Cb and Cr get +128.
_RGB_TO_YCBCR = np.array([[0.299, 0.587, 0.114],
                          [-0.168736, -0.331264, 0.5],
                          [0.5, -0.418688, -0.081312]], dtype=np.float32)


def coded_size(size: tuple[int, int]) -> tuple[int, int]:
    """``size`` (w, h) rounded up to even sides: the picture the encoder codes."""
    return size[0] + (size[0] & 1), size[1] + (size[1] & 1)


def tile_ycbcr(payload: bytes, codec: Codec, width: int, height: int) -> np.ndarray:
    """One tile as (height, width, 3) uint8 Y, Cb, Cr (full range)."""
    if codec is Codec.JPEG:
        image = Image.open(io.BytesIO(payload))
        image.draft("YCbCr", image.size)
        if image.mode != "YCbCr" or image.size != (width, height):
            raise ValueError(f"JPEG tile is {image.mode} {image.size[0]}x{image.size[1]}, expected YCbCr "
                             f"{width}x{height}")
        return np.asarray(image)
    rgb = decode(payload, codec, width, height).astype(np.float32)
    ycbcr = rgb @ _RGB_TO_YCBCR.T
    ycbcr[..., 1:] += 128.0
    return np.clip(np.rint(ycbcr), 0, 255).astype(np.uint8)


def compose_yuv420(size: tuple[int, int], tiles: Iterable[tuple[Rect, Codec, int, bytes]]) -> np.ndarray:
    """The frame of ``size`` (w, h) from its ``tiles`` (rect, codec, node, payload) as one
    yuv420p picture: (H·3/2, W) uint8 for the coded (even) size W×H — the Y plane, then the Cb
    and Cr planes of (H/2, W/2) each, row after row. The padding repeats the last row and column."""
    width, height = coded_size(size)
    ycbcr = np.empty((height, width, 3), dtype=np.uint8)
    for rect, codec, _, payload in tiles:
        ycbcr[rect.y:rect.y1, rect.x:rect.x1] = tile_ycbcr(payload, codec, rect.w, rect.h)
    if width != size[0]:
        ycbcr[:size[1], -1] = ycbcr[:size[1], -2]
    if height != size[1]:
        ycbcr[-1] = ycbcr[-2]
    planes = np.empty((height * 3 // 2, width), dtype=np.uint8)
    planes[:height] = ycbcr[..., 0]
    chroma = (height // 2, width // 2)
    flat = planes[height:].reshape(-1)
    flat[:chroma[0] * chroma[1]].reshape(chroma)[:] = ycbcr[::2, ::2, 1]
    flat[chroma[0] * chroma[1]:].reshape(chroma)[:] = ycbcr[::2, ::2, 2]
    return planes
