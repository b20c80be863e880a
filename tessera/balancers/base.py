"""The one small interface every balancer implements (Equalizer's equalizer.h habit).

A balancer receives what the coordinator measured and returns the next partition. It never
polls, never reads a clock (elapsed time comes in :class:`BalanceInput`), never does I/O, and is
deterministic for the same sequence of inputs.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from tessera.geometry import Rect


@dataclass(frozen=True, slots=True)
class Tile:
    """A screen rect and the node that renders it (``None``: any node may pull it)."""

    rect: Rect
    node_id: int | None


@dataclass(frozen=True, slots=True)
class Partition:
    """The tiles of one frame, exact cover of the screen.

    ``pull`` = False: each tile is pushed to its ``node_id``. ``pull`` = True (tile rotation):
    tiles are handed out in list order to whichever node is free first.
    """

    tiles: tuple[Tile, ...]
    pull: bool = False

    @property
    def rects(self) -> list[Rect]:
        return [t.rect for t in self.tiles]


@dataclass(frozen=True, slots=True)
class TileTiming:
    """Measured phases of one tile of the last complete frame, in milliseconds."""

    rect: Rect
    node_id: int
    render_ms: float
    readback_ms: float = 0.0
    encode_ms: float = 0.0
    send_ms: float = 0.0

    @property
    def phase_ms(self) -> tuple[float, float, float, float]:
        """The times in :data:`tessera.wire.protocol.NODE_PHASES` order."""
        return (self.render_ms, self.readback_ms, self.encode_ms, self.send_ms)

    @property
    def busy_ms(self) -> float:
        return self.render_ms + self.readback_ms + self.encode_ms + self.send_ms


@dataclass(frozen=True, slots=True)
class ProjectedGroups:
    """Screen-space boxes of primitive groups (seed 003 DPBP), clipped to the screen.

    ``boxes``: (K, 4) float64 pixel coordinates x0, y0, x1, y1 (origin top-left);
    ``weights``: (K,) float64 primitive counts.
    """

    boxes: np.ndarray
    weights: np.ndarray


@dataclass(frozen=True, slots=True)
class BalanceInput:
    """Everything a balancer may use to make the next frame's partition."""

    size: tuple[int, int]
    node_ids: tuple[int, ...]
    previous: Partition | None = None
    timings: tuple[TileTiming, ...] = ()
    weights: Mapping[int, float] = field(default_factory=dict)
    elapsed_ms: float = 0.0
    groups: ProjectedGroups | None = None

    def weight(self, node_id: int) -> float:
        return float(self.weights.get(node_id, 1.0))

    def previous_matches(self) -> bool:
        """True when ``previous`` was made for exactly the current nodes and screen size."""
        if self.previous is None:
            return False
        owners = sorted(t.node_id for t in self.previous.tiles if t.node_id is not None)
        if not self.previous.pull and owners != sorted(self.node_ids):
            return False
        width, height = self.size
        return all(t.rect.x1 <= width and t.rect.y1 <= height for t in self.previous.tiles) and (
            sum(t.rect.area for t in self.previous.tiles) == width * height
        )


def busy_by_node(timings: tuple[TileTiming, ...]) -> dict[int, float]:
    """Total busy milliseconds per node over a frame's tiles."""
    out: dict[int, float] = {}
    for timing in timings:
        out[timing.node_id] = out.get(timing.node_id, 0.0) + timing.busy_ms
    return out


def imbalance(busy_ms: Mapping[int, float]) -> float:
    """max/mean of node busy times (1.0 = perfect balance; 1.0 when nothing was measured)."""
    values = [v for v in busy_ms.values() if math.isfinite(v)]
    mean = sum(values) / len(values) if values else 0.0
    return max(values) / mean if mean > 0.0 else 1.0


#: Largest magnitude of a balancer parameter (a JSON integer may be too large for a float).
MAX_PARAM = 10**15


def _shown(value: Any) -> str:
    """``repr(value)`` cut to 60 characters, for an error message that echoes a client's input."""
    text = repr(value)
    return text if len(text) <= 60 else text[:59] + "…"


def _coerce_param(key: str, value: Any, default: Any) -> Any:
    """``value`` as the type of ``default``: bools only from bools, ints only from whole numbers,
    floats finite; anything else is a ValueError naming the parameter."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"balancer parameter {key!r} must be true or false, got {_shown(value)}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"balancer parameter {key!r} must be a number, got {_shown(value)}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"balancer parameter {key!r} must be finite")
    if abs(value) > MAX_PARAM:
        raise ValueError(f"balancer parameter {key!r} must be within ±{MAX_PARAM:.0e}")
    if isinstance(default, int):
        if not float(value).is_integer():
            raise ValueError(f"balancer parameter {key!r} must be a whole number, got {_shown(value)}")
        return int(value)
    return float(value)


class Balancer(ABC):
    """A balancing technique. Subclasses declare ``name`` and ``defaults`` (their parameters)."""

    name: ClassVar[str]
    defaults: ClassVar[Mapping[str, float | int | bool]] = {}
    #: True when the technique reads ``BalanceInput.groups`` (the coordinator projects them per frame).
    uses_groups: ClassVar[bool] = False

    def __init__(self, **params: Any) -> None:
        unknown = set(params) - set(self.defaults)
        if unknown:
            raise ValueError(f"balancer {self.name!r} has no parameters {sorted(unknown)}; "
                             f"it takes {sorted(self.defaults)}")
        merged = dict(self.defaults)
        for key, value in params.items():
            merged[key] = _coerce_param(key, value, merged[key])
        self.params: dict[str, Any] = merged
        self.validate_params()

    def validate_params(self) -> None:  # noqa: B027 - optional hook, most techniques need no checks
        """Raise ValueError for parameter values out of range."""

    @abstractmethod
    def partition(self, inputs: BalanceInput) -> Partition:
        """The next frame's partition."""
