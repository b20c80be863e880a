"""Where a frame's difference from another lies (issue 32, ``bench.lod_cameras --classes``): each
pixel of the model put in one class by the full-detail frame's depth, and each class's share of the
squared error. Pure numpy, no GL.

Classes, in order (a pixel takes the first that holds):

- ``outline``: within :data:`EDGE_PX` pixels of the background in either frame (the model's outline);
- ``depth_edge``: within :data:`EDGE_PX` pixels of a step in depth inside the model (two neighbours'
  view depths more than :data:`DEPTH_JUMP` apart, relative: one part of the model in front of another);
- ``grazing``, ``oblique``, ``facing``: the rest, by ``|cos|`` of the angle between the surface's
  normal (from the depth's differences) and the ray to the eye: under :data:`GRAZING`, under
  :data:`FACING`, from :data:`FACING` on.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: Pixels around the background and around depth steps that count as edges.
EDGE_PX = 2
#: Relative difference of two neighbours' view depths that makes a depth step.
DEPTH_JUMP = 0.02
#: ``|cos|`` between normal and ray under which a surface is grazing, and from which it faces the eye.
GRAZING, FACING = 0.3, 0.7
CLASSES = ("outline", "depth_edge", "grazing", "oblique", "facing")


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """(h, w) bool: the pixels within ``radius`` (a square of side 2 · radius + 1) of one of ``mask``'s."""
    h, w = mask.shape
    padded = np.pad(mask, radius)
    out = np.zeros((h, w), bool)
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            out |= padded[dy:dy + h, dx:dx + w]
    return out


def view_positions(depth: np.ndarray, near: float, far: float, fovy_deg: float) -> np.ndarray:
    """(h, w, 3) float64 each pixel's point in view space (``−z`` ahead, units of the scene) from
    ``depth`` (h, w) window depth in [0, 1] (row 0 at the top) of a perspective projection with the
    ``near`` and ``far`` planes and vertical field ``fovy_deg``, square pixels."""
    h, w = depth.shape
    ndc = np.asarray(depth, np.float64) * 2.0 - 1.0
    z = 2.0 * near * far / (far + near - ndc * (far - near))
    half = math.tan(math.radians(fovy_deg) / 2.0)
    ys = (1.0 - (np.arange(h) + 0.5) / h * 2.0) * half
    xs = ((np.arange(w) + 0.5) / w * 2.0 - 1.0) * half * w / h
    return np.stack([xs[None, :] * z, ys[:, None] * z, -z], axis=-1)


def facing(points: np.ndarray) -> np.ndarray:
    """(h, w) float64 ``|cos|`` of the angle between the surface through ``points`` (h, w, 3) (its
    normal from central differences, one-sided at the frame's border) and the ray to the eye."""
    across = np.gradient(points, axis=1)
    down = np.gradient(points, axis=0)
    normal = np.cross(across, down)
    length = np.linalg.norm(normal, axis=-1) * np.linalg.norm(points, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.nan_to_num(np.abs((normal * points).sum(axis=-1)) / length)


def depth_steps(z: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """(h, w) bool the pixels of ``inside`` on either side of a step in the view depths ``z`` (h, w)
    (two 4-neighbours more than :data:`DEPTH_JUMP` apart, relative to the nearer)."""
    steps = np.zeros(z.shape, bool)
    for axis in (0, 1):
        a = z[1:] if axis == 0 else z[:, 1:]
        b = z[:-1] if axis == 0 else z[:, :-1]
        with np.errstate(invalid="ignore", divide="ignore"):
            jump = np.abs(a - b) > DEPTH_JUMP * np.minimum(a, b)
        if axis == 0:
            steps[1:] |= jump
            steps[:-1] |= jump
        else:
            steps[:, 1:] |= jump
            steps[:, :-1] |= jump
    return steps & inside


def classify(depth: np.ndarray, empty: np.ndarray, empty_frame: np.ndarray, near: float, far: float,
             fovy_deg: float) -> np.ndarray:
    """(h, w) int8 each pixel's class (an index into :data:`CLASSES`; −1: background in both
    frames) from the full-detail frame's window ``depth`` (h, w) (1: nothing drawn) and the pixels
    (h, w) bool it leaves as background (``empty``) and the other frame does (``empty_frame``)."""
    points = view_positions(depth, near, far, fovy_deg)
    drawn = np.asarray(depth) < 1.0
    model = ~(empty & empty_frame)
    outline = dilate(empty | empty_frame, EDGE_PX) & model
    steps = dilate(depth_steps(-points[..., 2], drawn), EDGE_PX) & model & ~outline
    cos = facing(points)
    rest = model & ~outline & ~steps
    classes = np.full(depth.shape, -1, np.int8)
    classes[outline] = 0
    classes[steps] = 1
    classes[rest & (cos < GRAZING)] = 2
    classes[rest & (cos >= GRAZING) & (cos < FACING)] = 3
    classes[rest & (cos >= FACING)] = 4
    return classes


def error_shares(frame: np.ndarray, reference: np.ndarray, classes: np.ndarray) -> dict[str, Any]:
    """How the squared difference of ``frame`` from ``reference`` (h, w, 3) uint8 falls into the
    ``classes`` (h, w) of :func:`classify`: per class its ``error`` share and ``pixels`` share (of
    the frame); ``model_db`` the PSNR over the model's pixels alone and ``mean`` the mean signed
    difference there (of 255: < 0 darker than the reference)."""
    difference = frame.astype(np.float64) - reference
    error = (difference ** 2).sum(axis=2)
    total = max(float(error.sum()), 1e-12)
    model = classes >= 0
    shares: dict[str, Any] = {name: {"error": round(float(error[classes == k].sum()) / total, 3),
                                     "pixels": round(float((classes == k).mean()), 4)}
                              for k, name in enumerate(CLASSES)}
    mse = float(error[model].mean()) / 3.0 if model.any() else 0.0
    shares["model_db"] = round(10.0 * math.log10(255.0 ** 2 / mse), 2) if mse > 0 else math.inf
    shares["mean"] = round(float(difference[model].mean()), 2) if model.any() else 0.0
    return shares
