"""The coordinator's side of calibration (seed 003 §1): :class:`server.calibration.CalibrationRounds`
decides which node is measured when (the nodes' outstanding tiles, and sessions awaiting their first
frame, tell it whether they draw frames);
this sends the ``calibrate`` messages (on the default session's
scene, camera and size: every node holds it) and, once every node's times agree, gives the speeds to
the scheduler (the balancers' node weights) and to each node's stats."""

from __future__ import annotations

import logging
import time
from typing import Protocol

from server.calibration import CalibrationRounds, calibrate_message
from server.nodes import NodeLink
from tessera.scheduling.job_scheduler import JobScheduler
from tessera.wire.protocol import ProtocolError

log = logging.getLogger("tessera.server")


class CalibrationHost(Protocol):
    """What calibration needs of the service."""

    nodes: dict[int, NodeLink]
    scheduler: JobScheduler
    size: tuple[int, int]

    @property
    def settings(self): ...


class NodeCalibration:
    """Calibrates ``host``'s nodes, one at a time, in rounds."""

    def __init__(self, host: CalibrationHost) -> None:
        self.host = host
        self.rounds = CalibrationRounds()

    def request(self, node_ids: list[int]) -> None:
        """Measure these nodes (and every node known) again."""
        for node_id in node_ids:
            self.rounds.request(node_id)
        self.advance()

    def forget(self, node_id: int) -> None:
        self.rounds.forget(node_id)
        self.advance()

    def measured(self, link: NodeLink, ms: float) -> None:
        """``link``'s ``calibration`` message; ProtocolError when it was not asked for one."""
        if not self.rounds.measured(link.node_id, ms):
            raise ProtocolError("calibration result without a calibrate request")
        self.advance()

    def failed(self, link: NodeLink) -> None:
        """``link``'s calibration failed (a ``render_error`` of frame 0): it keeps its speed."""
        if not self.rounds.failed(link.node_id):
            raise ProtocolError("calibration failure without a calibrate request")
        self.advance()

    def advance(self) -> None:
        """Measure the next node, if it is time; once every node's times agree, apply the speeds."""
        host = self.host
        camera = host.scheduler.default.camera
        if camera is None:
            return
        scheduler = host.scheduler
        # A session's first frame goes first: a measurement on a node's one GL thread held up the
        # first frame of a 24.8M-triangle model by 0.5 s after a restart.
        busy = (any(schedule.outstanding for schedule in scheduler.nodes.values())
                or any(session.goes_first for session in scheduler.sessions.values()))
        jobs_only = busy and bool(scheduler.jobs) and all(job.job is not None for job in scheduler.in_flight.values())
        node_id = self.rounds.next_to_start(time.monotonic(), busy, jobs_only)
        if node_id is not None and node_id in host.nodes:
            # Drawn at the levels of detail once every node holds them (issue 32): at full detail a
            # measurement of the 24.8M-triangle model took a node 3 x 17 s away from moving frames.
            levels = None if scheduler.default.lod_bound is None else scheduler.default.lod.ceiling_px
            host.nodes[node_id].send(calibrate_message(camera, host.size, host.settings.scene, levels))
        calibrated = self.rounds.take_speeds()
        if calibrated is None:
            return
        times, speeds = calibrated
        for node_id, speed in speeds.items():
            link = host.nodes.get(node_id)
            if link is not None:
                host.scheduler.set_speed(node_id, speed.speed)
                link.calibration_ms, link.calibration_spread = times[node_id].ms, times[node_id].spread
                link.calibration_measurements, link.speed_distinct = times[node_id].measurements, speed.distinct
        log.info("nodes calibrated: %s", ", ".join(
            f"{node_id}: {times[node_id].ms:.2f} ms ±{100 * speed.spread:.0f} % of {times[node_id].measurements}, "
            f"×{speed.speed:.2f}" for node_id, speed in speeds.items()))
