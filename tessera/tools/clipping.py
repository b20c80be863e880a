"""Clip planes and a section box (issue 35): what part of a session's scene is cut away, part of
the frame-synchronous state every tile of a frame is drawn with.

A :class:`ClipState` holds up to :data:`MAX_PLANES` planes, each keeping the side its normal points
to, and an axis-aligned section box keeping what is inside it; what is kept is what every one of
them keeps. The nodes cut exactly (GL clip distances, :mod:`node.gl.clipping`) and draw the inside
of cut closed surfaces in the solid ``cap`` colour; their culling drops the chunks that lie wholly
in a cut-away half-space (:func:`clipped_boxes`), so a section of a big model is cheaper to draw.

JSON (``PUT /api/sessions/{id}/clip``, the ``clip`` of a ``render`` message)::

    {"planes": [{"point": [x, y, z], "normal": [x, y, z]}, …],
     "box": {"min": [x, y, z], "max": [x, y, z]} | null,
     "cap": true, "cap_color": [r, g, b]}

Every field is optional; ``cap_color`` is sRGB in 0…1. Bad values raise :class:`ClipError` naming
the field. Pure: numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Most clip planes a session may have (a section box comes on top of them).
MAX_PLANES = 6
#: The colour cut faces are capped with (sRGB, 0…1): a warm red, apart from most materials.
DEFAULT_CAP_COLOR = (0.80, 0.22, 0.16)
#: Largest coordinate magnitude accepted (float32 range, where the nodes compute).
MAX_COORDINATE = 1e30

Vec3 = tuple[float, float, float]


class ClipError(ValueError):
    """A clip state that cannot be used: bad numbers, too many planes, an empty box."""


def _vec3(value: Any, where: str) -> Vec3:
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ClipError(f"{where} must be a list of 3 numbers, got {_short(value)}")
    out = []
    for item in value:
        if isinstance(item, bool) or not isinstance(item, int | float | np.integer | np.floating):
            raise ClipError(f"{where} must be numbers, got {_short(value)}")
        number = float(item)
        if not math.isfinite(number) or abs(number) > MAX_COORDINATE:
            raise ClipError(f"{where} must be finite numbers of magnitude at most {MAX_COORDINATE:g}, "
                            f"got {_short(value)}")
        out.append(number)
    return (out[0], out[1], out[2])


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


@dataclass(frozen=True, slots=True)
class ClipPlane:
    """A plane through ``point`` keeping the side ``normal`` (unit length) points to."""

    point: Vec3
    normal: Vec3

    @classmethod
    def from_json(cls, data: Any, where: str = "plane") -> ClipPlane:
        if not isinstance(data, Mapping) or set(data) != {"point", "normal"}:
            raise ClipError(f"{where} must be an object {{\"point\": [x, y, z], \"normal\": [x, y, z]}}, "
                            f"got {_short(data)}")
        normal = np.asarray(_vec3(data["normal"], f"{where}.normal"))
        length = float(np.linalg.norm(normal))
        if not length > 0.0 or not math.isfinite(length):
            raise ClipError(f"{where}.normal must have a non-zero length, got {_short(data['normal'])}")
        unit = normal / length
        return cls(_vec3(data["point"], f"{where}.point"), (float(unit[0]), float(unit[1]), float(unit[2])))

    @property
    def halfspace(self) -> tuple[float, float, float, float]:
        """(a, b, c, d): the plane keeps a·x + b·y + c·z + d ≥ 0."""
        return (*self.normal, -float(np.dot(self.normal, self.point)))

    def to_json(self) -> dict[str, Any]:
        return {"point": list(self.point), "normal": list(self.normal)}


@dataclass(frozen=True, slots=True)
class ClipState:
    """Clip ``planes`` and a section ``box`` ((min, max) world corners; None: no box); ``cap``:
    the sRGB colour cut faces are capped with (None: not capped, the inside shows shaded)."""

    planes: tuple[ClipPlane, ...] = ()
    box: tuple[Vec3, Vec3] | None = None
    cap: Vec3 | None = DEFAULT_CAP_COLOR

    def __post_init__(self) -> None:
        if len(self.planes) > MAX_PLANES:
            raise ClipError(f"at most {MAX_PLANES} clip planes, got {len(self.planes)}")
        if self.box is not None and not all(lo < hi for lo, hi in zip(*self.box, strict=True)):
            raise ClipError(f"box min must be below box max on every axis, got {list(self.box[0])} and "
                            f"{list(self.box[1])}")

    @property
    def active(self) -> bool:
        """Something is cut away."""
        return bool(self.planes) or self.box is not None

    def halfspaces(self) -> np.ndarray:
        """(P, 4) float64 (a, b, c, d) rows, what is kept lying where every a·x + b·y + c·z + d ≥ 0:
        the planes, then the box's six faces (−x, +x, −y, +y, −z, +z)."""
        rows = np.asarray([plane.halfspace for plane in self.planes], dtype=np.float64).reshape(-1, 4)
        if self.box is None:
            return rows
        lo, hi = self.box
        faces = np.zeros((6, 4))
        for axis in range(3):
            faces[2 * axis, axis], faces[2 * axis, 3] = 1.0, -lo[axis]
            faces[2 * axis + 1, axis], faces[2 * axis + 1, 3] = -1.0, hi[axis]
        return np.concatenate([rows, faces])

    @classmethod
    def from_json(cls, data: Any) -> ClipState:
        """Validate the JSON of the module docstring; raises ClipError naming the field."""
        if isinstance(data, ClipState):
            return data
        if not isinstance(data, Mapping):
            raise ClipError("a clip state must be a JSON object")
        unknown = sorted(str(key) for key in data if key not in ("planes", "box", "cap", "cap_color"))
        if unknown:
            raise ClipError(f"unknown clip fields {unknown}; expected any of planes, box, cap, cap_color")
        planes = data.get("planes") or []
        if not isinstance(planes, list):
            raise ClipError("planes must be a list")
        if len(planes) > MAX_PLANES:
            raise ClipError(f"at most {MAX_PLANES} clip planes, got {len(planes)}")
        box = data.get("box")
        if box is not None and (not isinstance(box, Mapping) or set(box) != {"min", "max"}):
            raise ClipError(f"box must be an object {{\"min\": [x, y, z], \"max\": [x, y, z]}} or null, "
                            f"got {_short(box)}")
        cap = data.get("cap", True)
        if not isinstance(cap, bool):
            raise ClipError(f"cap must be true or false, got {_short(cap)}")
        color = _vec3(data.get("cap_color", DEFAULT_CAP_COLOR), "cap_color")
        if not all(0.0 <= c <= 1.0 for c in color):
            raise ClipError(f"cap_color must be three numbers in 0..1, got {list(color)}")
        return cls(tuple(ClipPlane.from_json(plane, f"planes[{i}]") for i, plane in enumerate(planes)),
                   None if box is None else (_vec3(box["min"], "box.min"), _vec3(box["max"], "box.max")),
                   color if cap else None)

    def to_json(self) -> dict[str, Any]:
        return {"planes": [plane.to_json() for plane in self.planes],
                "box": None if self.box is None else {"min": list(self.box[0]), "max": list(self.box[1])},
                "cap": self.cap is not None, "cap_color": list(self.cap or DEFAULT_CAP_COLOR)}


def clipped_boxes(boxes: np.ndarray, halfspaces: np.ndarray) -> np.ndarray:
    """(K,) bool: which of the world boxes ``boxes`` (K, 2, 3) as (min, max) lie wholly in the
    cut-away part of one of ``halfspaces`` (P, 4) (:meth:`ClipState.halfspaces`): their chunks
    need not be drawn. Conservative (the box's corner nearest the kept side is tested)."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    planes = np.asarray(halfspaces, dtype=np.float64).reshape(-1, 4)
    if planes.shape[0] == 0:
        return np.zeros(boxes.shape[0], dtype=bool)
    center, extent = (boxes[:, 0] + boxes[:, 1]) * 0.5, (boxes[:, 1] - boxes[:, 0]) * 0.5
    distance = center @ planes[:, :3].T + planes[:, 3]
    radius = extent @ np.abs(planes[:, :3]).T
    outside = np.any(distance < -radius, axis=1)
    return outside
