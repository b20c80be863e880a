"""A connected render node as the coordinator's adapter sees it: identity, scene state, outbox.
What it owes and its timings live in the scheduler's :class:`tessera.scheduling.node_table.NodeSchedule`."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tessera.scheduling.node_table import NodeSchedule
from tessera.wire.mesh_update import is_mesh_spec
from tessera.wire.messages import Message
from tessera.wire.protocol import NODE_PHASES


@dataclass
class NodeLink:
    """One node's connection state."""

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
    #: Sort-last: the data partition version whose share the node holds (``triangles`` are the share's).
    share: int | None = None
    can_calibrate: bool = False
    #: Its calibration (:mod:`server.calibration`): time, spread (max/min − 1 of its agreeing times),
    #: measurements, and whether the nodes' speeds differ beyond their spreads.
    calibration_ms: float | None = None
    calibration_spread: float | None = None
    calibration_measurements: int = 0
    speed_distinct: bool = False
    tiles_dropped: int = 0
    #: (frame id, tile id) of the binary tile just received, until its ``tile_sent``.
    last_tile: tuple[int, int] | None = None
    #: Issue 31: its resident memory and what it holds for scenes (MB, as it last said), each
    #: scene's MB by spec, and the scenes it is loading: spec → (fraction, message).
    rss_mb: float | None = None
    held_mb: float | None = None
    scene_mb: dict[str, float] = field(default_factory=dict)
    #: The triangles it holds of each scene it reported ready, by spec (sort-last: its share's).
    scene_triangles: dict[str, int] = field(default_factory=dict)
    loading: dict[str, tuple[float, str]] = field(default_factory=dict)
    #: Control messages (text) and meshes (binary, issue 33), sent in order.
    outbox: asyncio.Queue[str | bytes] = field(default_factory=asyncio.Queue)

    @property
    def ready(self) -> bool:
        return self.state == "ready"

    def forget_scenes_not_shown(self, shown: Collection[str]) -> None:
        """Forget the triangles of the scenes not in ``shown`` and the MB of the mesh steps not in
        it (a node keeps only a group's newest steps; each step is a scene of its own, and a
        simulation sends thousands)."""
        self.scene_triangles = {spec: n for spec, n in self.scene_triangles.items() if spec in shown}
        self.scene_mb = {spec: mb for spec, mb in self.scene_mb.items() if spec in shown or not is_mesh_spec(spec)}

    def send(self, message: Message) -> None:
        """Queue a control message; the connection's writer task sends it in order."""
        self.outbox.put_nowait(message.to_text())

    def send_bytes(self, data: bytes) -> None:
        """Queue a binary message (a mesh, :mod:`tessera.wire.mesh_update`) in order with the others."""
        self.outbox.put_nowait(data)

    def describe(self, schedule: NodeSchedule) -> dict[str, Any]:
        phases = schedule.last_phases
        return {
            "id": self.node_id,
            "slot": schedule.slot,
            "name": self.name,
            "renderer": self.renderer,
            "state": self.state,
            "scene_progress": round(self.progress, 3),
            "scene_message": self.scene_message,
            "triangles": self.triangles,
            "triangles_loaded": self.triangles,
            "share": self.share,
            "tiles": schedule.last_tiles,
            "readback": schedule.last_readback,
            **{f"{phase}_ms": round(phases.get(phase, 0.0), 3) for phase in NODE_PHASES},
            "busy_ms": round(sum(phases.values()), 3),
            "speed": round(schedule.speed, 4),
            "calibration_ms": None if self.calibration_ms is None else round(self.calibration_ms, 3),
            "calibration_spread": None if self.calibration_spread is None else round(self.calibration_spread, 4),
            "calibration_measurements": self.calibration_measurements,
            "speed_distinct": self.speed_distinct,
            "slowdown": self.slowdown,
            "rss_mb": self.rss_mb,
            "held_mb": self.held_mb,
            "tiles_rendered": schedule.tiles_rendered,
            "tiles_dropped": self.tiles_dropped,
            "outstanding": len(schedule.outstanding),
            "suspect": schedule.suspect,
            "backups": schedule.backups,
            **schedule.counters,
        }
