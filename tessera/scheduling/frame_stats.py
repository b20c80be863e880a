"""Rolling figures for ``/api/stats`` and ``/metrics``: frame rate, latency and imbalance."""

from __future__ import annotations

from collections import deque

from tessera.balancers.base import imbalance

WINDOW_FRAMES = 60


class FrameStats:
    def __init__(self) -> None:
        self._published: deque[float] = deque(maxlen=WINDOW_FRAMES + 1)
        self._latencies: deque[float] = deque(maxlen=WINDOW_FRAMES)
        self._imbalances: deque[float] = deque(maxlen=WINDOW_FRAMES)
        self.frames_published = 0

    def record_publish(self, now: float, latency_s: float | None) -> None:
        """A frame published at ``now`` (s); ``latency_s``: input → publish time when it is the first
        frame to show a new input, None for frames that only re-render (settling, still)."""
        self._published.append(now)
        if latency_s is not None:
            self._latencies.append(latency_s * 1000.0)
        self.frames_published += 1

    def record_balance(self, busy_ms_by_node: dict[int, float]) -> None:
        self._imbalances.append(imbalance(busy_ms_by_node))

    def reset_imbalance(self) -> None:
        self._imbalances.clear()

    def fps(self, now: float) -> float:
        """Published frames per second over the last ``WINDOW_FRAMES`` frames (0 when idle > 2 s)."""
        if len(self._published) < 2 or now - self._published[-1] > 2.0:
            return 0.0
        span = self._published[-1] - self._published[0]
        return (len(self._published) - 1) / span if span > 0 else 0.0

    @property
    def latency_ms(self) -> float:
        """Mean input → publish time (ms) of the recent frames that answered a new input."""
        return sum(self._latencies) / len(self._latencies) if self._latencies else 0.0

    @property
    def imbalance(self) -> float:
        return self._imbalances[-1] if self._imbalances else 1.0

    @property
    def imbalance_avg(self) -> float:
        return sum(self._imbalances) / len(self._imbalances) if self._imbalances else 1.0
