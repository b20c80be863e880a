"""A token bucket: the per-socket message-rate limit of the coordinator's WebSockets.

Pure: the clock is passed in (seconds, any monotonic origin), nothing is read or slept. A bucket
holds at most ``burst`` tokens and refills at ``rate`` tokens per second; each message takes one.
A peer may send ``burst`` messages at once and ``rate`` per second for ever; one that keeps
sending faster empties the bucket and is refused.
"""

from __future__ import annotations

import math


class TokenBucket:
    """``rate`` tokens per second, at most ``burst`` held; full at ``now``."""

    def __init__(self, rate: float, burst: float, now: float) -> None:
        if not (math.isfinite(rate) and rate > 0):
            raise ValueError(f"rate must be a finite number > 0, got {rate!r}")
        if not (math.isfinite(burst) and burst >= 1):
            raise ValueError(f"burst must be a finite number >= 1, got {burst!r}")
        self.rate = rate
        self.burst = burst
        self.tokens = burst
        self.updated = now

    def take(self, now: float, cost: float = 1.0) -> bool:
        """Take ``cost`` tokens at ``now`` if the bucket holds them; False (nothing taken) if not.
        A clock that steps back refills nothing."""
        if now > self.updated:
            self.tokens = min(self.burst, self.tokens + (now - self.updated) * self.rate)
            self.updated = now
        if self.tokens >= cost:
            self.tokens -= cost
            return True
        return False
