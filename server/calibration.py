"""Node calibration for heterogeneous clusters (seed 003 §1): every node renders the same central
screen region without output; its time tᵢ gives the performance Pᵢ = t_max / tᵢ (slowest = 1,
:func:`tessera.balancers.hetero.calibration_weights`).

Nodes are calibrated one at a time so that nodes sharing a machine do not blur each other's
times. Pure bookkeeping: the service sends the messages and passes clock readings in.
"""

from __future__ import annotations

from collections import deque

from tessera.balancers.hetero import calibration_region
from tessera.geometry import Camera
from tessera.wire.messages import Calibrate

CALIBRATION_REPEATS = 3
CALIBRATION_TIMEOUT_S = 30.0


def calibrate_message(camera: Camera, size: tuple[int, int], scene: str | None = None) -> Calibrate:
    """Calibrate on ``scene`` (the default session's: every node loads it) at ``size``."""
    return Calibrate(camera=camera, size=size, rect=calibration_region(size), repeats=CALIBRATION_REPEATS,
                     scene=scene)


class CalibrationQueue:
    """Which node calibrates next; at most one at a time, a silent node is skipped after a timeout."""

    def __init__(self) -> None:
        self.waiting: deque[int] = deque()
        self.current: int | None = None
        self.started_at = 0.0

    def request(self, node_id: int) -> None:
        if node_id != self.current and node_id not in self.waiting:
            self.waiting.append(node_id)

    def forget(self, node_id: int) -> None:
        if node_id in self.waiting:
            self.waiting.remove(node_id)
        if self.current == node_id:
            self.current = None

    def finished(self, node_id: int) -> bool:
        """True when ``node_id`` was the node calibrating (its result is expected)."""
        if self.current != node_id:
            return False
        self.current = None
        return True

    def next_to_start(self, now: float) -> int | None:
        """The node to calibrate now, if none is calibrating (or the current one timed out)."""
        if self.current is not None and now - self.started_at < CALIBRATION_TIMEOUT_S:
            return None
        if not self.waiting:
            self.current = None
            return None
        self.current, self.started_at = self.waiting.popleft(), now
        return self.current
