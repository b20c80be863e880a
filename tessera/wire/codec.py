"""Tile codecs: RGB pixel arrays to compressed bytes and back (Pillow / libjpeg-turbo).

Pure: bytes and arrays in, bytes and arrays out. Pixel arrays are ``uint8`` of shape
(height, width, 3), row 0 at the top.
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from enum import IntEnum

import numpy as np
from PIL import Image

from tessera.geometry import Rect


class Codec(IntEnum):
    RAW = 0
    JPEG = 1
    PNG = 2

    @classmethod
    def parse(cls, name: str) -> Codec:
        try:
            return cls[name.upper()]
        except KeyError:
            raise ValueError(f"unknown codec {name!r}; choose one of {[c.name.lower() for c in cls]}") from None


class CodecError(ValueError):
    """Bytes that do not decode to the expected image."""


def encode(pixels: np.ndarray, codec: Codec, jpeg_quality: int = 85) -> bytes:
    """Compress a (h, w, 3) uint8 array."""
    if pixels.dtype != np.uint8 or pixels.ndim != 3 or pixels.shape[2] != 3:
        raise ValueError(f"expected (h, w, 3) uint8 pixels, got {pixels.shape} {pixels.dtype}")
    if codec is Codec.RAW:
        return np.ascontiguousarray(pixels).tobytes()
    buffer = io.BytesIO()
    image = Image.fromarray(pixels, "RGB")
    if codec is Codec.JPEG:
        image.save(buffer, "JPEG", quality=jpeg_quality, subsampling=0 if jpeg_quality >= 90 else 2)
    else:
        image.save(buffer, "PNG", compress_level=1)
    return buffer.getvalue()


def decode(data: bytes, codec: Codec, width: int, height: int) -> np.ndarray:
    """Decompress to a (height, width, 3) uint8 array; raises CodecError on size or format mismatch."""
    if codec is Codec.RAW:
        if len(data) != width * height * 3:
            raise CodecError(f"raw tile has {len(data)} bytes, expected {width * height * 3}")
        return np.frombuffer(data, dtype=np.uint8).reshape(height, width, 3)
    try:
        with Image.open(io.BytesIO(data)) as image:
            if image.size != (width, height):
                raise CodecError(f"{codec.name} tile is {image.size[0]}x{image.size[1]}, expected {width}x{height}")
            return np.asarray(image.convert("RGB"))
    except CodecError:
        raise
    except Exception as exc:  # Pillow raises many types for corrupt input
        raise CodecError(f"undecodable {codec.name} tile: {exc}") from None


def paste_into(image: np.ndarray, tiles: Iterable[tuple[Rect, Codec, int, bytes]]) -> np.ndarray:
    """``image`` (h, w, 3) uint8 with each (rect, codec, node, payload) tile decoded into its rect."""
    for rect, codec, _, payload in tiles:
        image[rect.y:rect.y1, rect.x:rect.x1] = decode(payload, codec, rect.w, rect.h)
    return image


def encode_png(pixels: np.ndarray) -> bytes:
    """Lossless PNG of a (h, w, 3) uint8 array (used for published frames)."""
    return encode(pixels, Codec.PNG)
