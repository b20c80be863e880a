"""Fair shares of node time among sessions: start-time fair queuing on measured cost,
the virtual-time form of Deficit Round Robin (Shreedhar & Varghese 1995; Linux ``sch_drr``).

Each session's *served* time is the node time (busy ms: render + read-back + encode, summed over
the nodes) its frames took. When nodes free up and several sessions owe a frame, the least served
starts first; and a session more than one frame ahead of the least served backlogged one (owing a
frame or with frames in flight) waits, as a flow whose deficit is spent waits for the next round
in DRR: otherwise sessions that each keep their frames in flight would get equal frame rates,
not equal node time. A frame is charged when it starts, at the session's last measured frame cost (so a
session with a frame in flight is not picked again for free), and the charge is corrected to the
measured cost when the frame completes (or refunded when it is dropped); a new session's first
frame is charged at the costliest other session's last frame, so a long first frame does not keep
it the least served while the others wait with nodes free. A session that had no
work for :data:`IDLE_S` (no frame owed, none in flight) is lifted to the least served of the
active ones when it wants again: an idle session is owed nothing, and one that joins cannot
starve the others. Weights scale the charge (a session of weight 2 gets twice the node time).
A frame drawn while only some nodes hold its session's scene is charged its node time times the
frame's *scarcity* (the nodes over those that hold the scene): the few holders are the nodes every
other session's frames wait at too (docs/explanation/sessions.md). The node shares reported stay
the node time taken. A session's render jobs (posters, films) take node time outside its frames:
it counts as served and in its node share (:meth:`FairShare.spent`), as any other work of it.
Pure: the clock comes in as ``now`` (s).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

#: The charge of the first session's first frame, before any was measured (ms of node time).
FIRST_FRAME_MS = 10.0
#: A session without work for this long (s) is idle: it is owed nothing when it comes back (the
#: gap between a frame and the viewer's next camera is not idleness).
IDLE_S = 0.5
#: The window (s) a session's node share is figured over.
SHARE_WINDOW_S = 5.0
#: How many of each session's recent frames its node share is figured over at most.
SHARE_WINDOW_FRAMES = 60


class FairShare:
    """Served node time per session id; see the module docstring."""

    def __init__(self) -> None:
        self.served: dict[str, float] = {}
        self.weights: dict[str, float] = {}
        self._cost: dict[str, float] = {}
        self._busy: dict[str, deque[tuple[float, float]]] = {}
        self._active_at: dict[str, float] = {}
        #: Node time taken outside frames (render jobs), (when, ms), the last :data:`SHARE_WINDOW_S`.
        self._outside: dict[str, deque[tuple[float, float]]] = {}

    def add(self, session: str, weight: float = 1.0) -> None:
        """A new session, starting at the least served of the others (owed nothing)."""
        if not weight > 0.0:
            raise ValueError(f"a session's weight must be > 0, got {weight}")
        self.served[session] = min(self.served.values(), default=0.0)
        self.weights[session] = weight
        self._cost[session] = max(self._cost.values(), default=FIRST_FRAME_MS)
        self._busy[session] = deque(maxlen=SHARE_WINDOW_FRAMES)

    def remove(self, session: str) -> None:
        for book in (self.served, self.weights, self._cost, self._busy, self._active_at, self._outside):
            book.pop(session, None)

    def order(self, wanting: Iterable[str], busy: Iterable[str], now: float) -> list[str]:
        """The sessions of ``wanting`` (they owe a frame) that may start one, least served first:
        none more than the costliest backlogged session's frame ahead of the least served
        backlogged one (``busy`` ones have frames in flight). A wanting session idle for
        :data:`IDLE_S` before ``now`` is first lifted to the least served of those active within it."""
        wanting, busy = list(wanting), set(busy)
        active = [s for s in self.served if now - self._active_at.get(s, -IDLE_S - 1.0) <= IDLE_S]
        floor = min((self.served[s] for s in active), default=None)
        for session in wanting:
            if floor is not None and session not in active and self.served[session] < floor:
                self.served[session] = floor
        for session in (*wanting, *busy):
            self._active_at[session] = now
        backlogged = {*wanting, *busy}
        return sorted((s for s in wanting if self.in_turn(s, backlogged)), key=lambda s: (self.served[s], s))

    def in_turn(self, session: str, backlogged: Iterable[str]) -> bool:
        """``session`` is at most the costliest ``backlogged`` session's frame ahead of the least
        served of them (see the module docstring)."""
        known = [s for s in {*backlogged, session} if s in self.served]
        least = min((self.served[s] for s in known), default=0.0)
        ahead = max((self._cost[s] / self.weights[s] for s in known), default=0.0)
        return self.served[session] <= least + ahead

    def others_active(self, session: str, now: float) -> bool:
        """A session other than ``session`` had work within :data:`IDLE_S` before ``now``."""
        return any(now - at <= IDLE_S for other, at in self._active_at.items() if other != session)

    def frame_cost(self, session: str) -> float | None:
        """The node time (ms) the session's last complete frame took (None before one)."""
        return self._cost[session] if self._busy[session] else None

    def started(self, session: str, scarcity: float = 1.0) -> float:
        """A frame of ``session`` started: charged at its last measured cost times its ``scarcity``
        (see the module docstring); returns the charge."""
        charge = self._cost[session] * scarcity / self.weights[session]
        self.served[session] += charge
        return charge

    def finished(self, session: str, charge: float, busy_ms: float | None, now: float,
                 scarcity: float = 1.0) -> None:
        """A frame charged ``charge`` ended at ``now`` (s) having cost ``busy_ms`` of node time
        (None: dropped, refunded), counted ``scarcity`` times."""
        if session not in self.served:
            return
        self.served[session] -= charge
        if busy_ms is not None:
            self.served[session] += busy_ms * scarcity / self.weights[session]
            self._cost[session] = max(busy_ms, 0.1)
            self._busy[session].append((now, busy_ms))

    def spent(self, session: str, busy_ms: float, now: float) -> None:
        """``session`` took ``busy_ms`` of node time outside its frames (a render job's tile),
        ending at ``now``: served, and in its node share; its frame cost stays its frames'."""
        if session not in self.served:
            return
        self.served[session] += busy_ms / self.weights[session]
        outside = self._outside.setdefault(session, deque())
        outside.append((now, busy_ms))
        while outside and outside[0][0] < now - SHARE_WINDOW_S:
            outside.popleft()

    def busy_ms(self, session: str, now: float, window_s: float = SHARE_WINDOW_S) -> float:
        """Node time (ms) the session's frames (and render jobs' tiles) that ended in the last
        ``window_s`` seconds took."""
        since = now - window_s
        return sum(ms for book in (self._busy, self._outside) for at, ms in book.get(session, ()) if at >= since)

    def node_share(self, session: str, now: float, window_s: float = SHARE_WINDOW_S) -> float:
        """The session's fraction of the node time all sessions' frames took over the last
        ``window_s`` seconds (0 when none took any)."""
        total = sum(self.busy_ms(s, now, window_s) for s in self.served)
        return self.busy_ms(session, now, window_s) / total if total > 0.0 else 0.0
