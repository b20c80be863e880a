"""Environment maps for image-based lighting: the default neutral studio (generated here, nothing
downloaded) and Radiance ``.hdr`` files (``--environment FILE.hdr``). No GL here.

An environment is an equirectangular (H, W, 3) float32 array of linear radiance, W = 2H, row 0 at
the zenith (+y up, as glTF), column u at azimuth φ = (u − ½)·2π from −z towards +x:
direction (sin θ sin φ, cos θ, −sin θ cos φ) for polar angle θ = v·π. The fragment shader looks
a direction up with the same mapping (:mod:`node.gl.shading`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

#: The studio's height in texels (width twice that).
STUDIO_HEIGHT = 128
#: Softboxes of the studio: (azimuth°, elevation°, half width°, half height°, radiance).
STUDIO_SOFTBOXES = ((-50.0, 35.0, 22.0, 16.0, 4.0), (130.0, 25.0, 18.0, 14.0, 1.5), (0.0, 80.0, 40.0, 9.0, 2.0))
#: Radiance of the studio's walls at the horizon, at the zenith, and of its floor.
STUDIO_HORIZON, STUDIO_ZENITH, STUDIO_FLOOR = 0.3, 0.45, 0.12


class EnvironmentError(ValueError):
    """An environment file that cannot be read; the message names the file and the reason."""


def directions(height: int) -> np.ndarray:
    """(height, 2·height, 3) float64 unit directions of the texel centres of an equirectangular map."""
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = ((np.arange(2 * height) + 0.5) / (2 * height) - 0.5) * 2.0 * np.pi
    sin_theta = np.sin(theta)[:, None]
    return np.stack(np.broadcast_arrays(sin_theta * np.sin(phi), np.cos(theta)[:, None], -sin_theta * np.cos(phi)),
                    axis=-1)


def solid_angles(height: int) -> np.ndarray:
    """(height, 2·height) float64 solid angle of each texel of an equirectangular map, sr (sums to 4π)."""
    theta = (np.arange(height) + 0.5) / height * np.pi
    row = (np.pi / height) * (2.0 * np.pi / (2 * height)) * np.sin(theta)
    return np.repeat(row[:, None], 2 * height, axis=1)


def studio_environment(height: int = STUDIO_HEIGHT) -> np.ndarray:
    """The neutral grey studio: walls brightening towards the zenith, a darker floor and three
    white softboxes (key left-front, fill behind, a strip overhead) with soft edges. (h, 2h, 3)."""
    d = directions(height)
    y = d[..., 1]
    walls = STUDIO_HORIZON + (STUDIO_ZENITH - STUDIO_HORIZON) * np.clip(y, 0.0, 1.0)
    blend = np.clip(y / 0.08 + 0.5, 0.0, 1.0)
    radiance = STUDIO_FLOOR + (walls - STUDIO_FLOOR) * blend * blend * (3.0 - 2.0 * blend)
    azimuth = np.degrees(np.arctan2(d[..., 0], -d[..., 2]))
    elevation = np.degrees(np.arcsin(np.clip(y, -1.0, 1.0)))
    for center_az, center_el, half_w, half_h, level in STUDIO_SOFTBOXES:
        off_az = (azimuth - center_az + 180.0) % 360.0 - 180.0
        inside = (_soft_edge(np.abs(off_az) * np.cos(np.radians(elevation)), half_w)
                  * _soft_edge(np.abs(elevation - center_el), half_h))
        radiance = radiance + level * inside
    return np.repeat(radiance[..., None], 3, axis=-1).astype(np.float32)


def _soft_edge(distance: np.ndarray, half: float, soft: float = 4.0) -> np.ndarray:
    """1 inside ``half`` degrees, 0 beyond ``half + soft``, smooth between."""
    t = np.clip((half + soft - distance) / soft, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def read_hdr(path: Path) -> np.ndarray:
    """A Radiance RGBE ``.hdr`` file (flat or run-length encoded scanlines, ``-Y h +X w``) as an
    (h, w, 3) float32 linear radiance array, resampled to the equirectangular W = 2H layout if its
    aspect differs. Raises EnvironmentError."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise EnvironmentError(f"environment file {path}: unreadable ({exc.strerror or exc})") from None
    try:
        rgbe = _decode_rgbe(data)
    except (ValueError, IndexError) as exc:
        raise EnvironmentError(f"environment file {path}: not a Radiance .hdr ({exc})") from None
    mantissa = rgbe[..., :3].astype(np.float32)
    exponent = rgbe[..., 3].astype(np.int32)
    scale = np.where(exponent > 0, np.ldexp(np.float32(1.0), exponent - 136), 0.0).astype(np.float32)
    image = mantissa * scale[..., None]
    height, width = image.shape[:2]
    if width != 2 * height:
        columns = np.minimum((np.arange(2 * height) * width) // (2 * height), width - 1)
        image = image[:, columns]
    return np.ascontiguousarray(image)


def _decode_rgbe(data: bytes) -> np.ndarray:
    """(h, w, 4) uint8 RGBE pixels of a Radiance file's bytes."""
    header_end = data.find(b"\n\n")
    if not data.startswith((b"#?RADIANCE", b"#?RGBE")) or header_end < 0:
        raise ValueError("no #?RADIANCE header")
    if b"FORMAT=32-bit_rle_rgbe" not in data[:header_end] and b"FORMAT=" in data[:header_end]:
        raise ValueError("only the 32-bit_rle_rgbe format is supported")
    line_end = data.index(b"\n", header_end + 2)
    match = re.fullmatch(rb"-Y (\d+) \+X (\d+)", data[header_end + 2:line_end].strip())
    if match is None:
        raise ValueError("only the standard -Y H +X W orientation is supported")
    height, width = int(match[1]), int(match[2])
    if not (0 < height <= 8192 and 0 < width <= 16384):
        raise ValueError(f"unreasonable size {width}x{height}")
    body = np.frombuffer(data, np.uint8, offset=line_end + 1)
    if not (8 <= width < 32768) or len(body) < 4 or body[0] != 2 or body[1] != 2 or body[2] & 0x80:
        return body[: height * width * 4].reshape(height, width, 4).copy()
    out = np.empty((height, 4, width), np.uint8)
    position = 0
    for row in range(height):
        if body[position] != 2 or body[position + 1] != 2:
            raise ValueError(f"scanline {row}: bad run-length header")
        position += 4
        for channel in range(4):
            position = _decode_runs(body, position, out[row, channel])
    return out.transpose(0, 2, 1).copy()


def _decode_runs(body: np.ndarray, position: int, target: np.ndarray) -> int:
    """Decode one channel of one run-length scanline into ``target`` (w,); returns the next byte's
    position. The format is a sequence of runs, each a count byte and its bytes, so it is read run
    by run (a scanline has a handful of runs per 128 pixels)."""
    filled, width = 0, len(target)
    while filled < width:
        count = int(body[position])
        if count > 128:
            count -= 128
            target[filled:filled + count] = body[position + 1]
            position += 2
        else:
            target[filled:filled + count] = body[position + 1:position + 1 + count]
            position += 1 + count
        if count == 0 or filled + count > width:
            raise ValueError("a run overruns its scanline")
        filled += count
    return position


def write_hdr(path: Path, image: np.ndarray) -> None:
    """Write (h, w, 3) float linear radiance as a flat (uncompressed) Radiance file."""
    image = np.maximum(np.asarray(image, np.float64), 0.0)
    peak = image.max(axis=-1)
    mantissa, exponent = np.frexp(peak)
    scale = np.divide(mantissa * 256.0, peak, out=np.zeros_like(peak), where=peak > 1e-32)
    rgbe = np.zeros((*image.shape[:2], 4), np.uint8)
    rgbe[..., :3] = np.clip(image * scale[..., None], 0, 255).astype(np.uint8)
    rgbe[..., 3] = np.where(peak > 1e-32, exponent + 128, 0).astype(np.uint8)
    height, width = image.shape[:2]
    header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n".encode()
    path.write_bytes(header + rgbe.tobytes())
