"""A connected render node as the coordinator sees it: identity, scene state, outbox, work owed."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tessera.protocol import encode_json


@dataclass
class NodeLink:
    """One node's connection state. ``outstanding`` maps (frame_id, tile_id) → monotonic
    dispatch time for every tile the node owes."""

    node_id: int
    name: str
    renderer: str
    close: Callable[[int, str], None]
    slowdown: float = 1.0
    state: str = "loading"
    scene_message: str = ""
    progress: float = 0.0
    triangles: int = 0
    bounds: np.ndarray | None = None
    groups: dict[str, Any] | None = None
    speed: float = 1.0
    can_calibrate: bool = False
    calibration_ms: float | None = None
    idle_since: float = 0.0
    outstanding: dict[tuple[int, int], float] = field(default_factory=dict)
    outbox: asyncio.Queue[str] = field(default_factory=asyncio.Queue)
    last_tiles: list[list[int]] = field(default_factory=list)
    last_phases: dict[str, float] = field(default_factory=dict)
    counters: dict[str, Any] = field(default_factory=dict)
    tiles_rendered: int = 0

    @property
    def ready(self) -> bool:
        return self.state == "ready"

    def send(self, message: dict[str, Any]) -> None:
        """Queue a control message; the connection's writer task sends it in order."""
        self.outbox.put_nowait(encode_json(message))

    def describe(self) -> dict[str, Any]:
        phases = self.last_phases
        return {
            "id": self.node_id,
            "name": self.name,
            "renderer": self.renderer,
            "state": self.state,
            "scene_progress": round(self.progress, 3),
            "scene_message": self.scene_message,
            "triangles": self.triangles,
            "tiles": self.last_tiles,
            "render_ms": round(phases.get("render", 0.0), 3),
            "readback_ms": round(phases.get("readback", 0.0), 3),
            "encode_ms": round(phases.get("encode", 0.0), 3),
            "send_ms": round(phases.get("send", 0.0), 3),
            "busy_ms": round(sum(phases.values()), 3),
            "speed": round(self.speed, 4),
            "calibration_ms": None if self.calibration_ms is None else round(self.calibration_ms, 3),
            "slowdown": self.slowdown,
            "tiles_rendered": self.tiles_rendered,
            "outstanding": len(self.outstanding),
            **self.counters,
        }
