"""Node calibration for heterogeneous clusters (seed 003 §1): every node renders the same central
screen region without output; its time tᵢ gives the performance Pᵢ = t_max / tᵢ (slowest = 1), the
balancers' node weight.

Speeds a user can believe (issue 38: three identical containers read ×1.00, ×1.94 and ×2.99 after
one measurement each, the first taken while the others still loaded their scene on the same cores):

* nodes are measured one at a time (nodes sharing a machine do not blur each other's times), in
  rounds of one measurement of each node, so that every node's measurements spread over the same
  stretch of time and count as many; and while the cluster draws frames (start-up's first frames and their
  still), a measurement waits up to :data:`QUIET_WAIT_S` for it to finish; while it draws nothing
  but render jobs (posters, films: the lowest priority work, which keeps every node busy for
  minutes), it waits for them to end: a time taken beside them is disturbed anyway, and the
  measured node's job tiles would wait for its renders of the region (about a second each on
  this machine while a film of the 990k scan drew);
* a node joining, or a calibration asked for, measures every node again: the others' times were
  taken while it loaded;
* rounds go on until every node's last :data:`AGREEING` times agree within :data:`AGREEMENT`
  (max/min − 1), at most :data:`MAX_MEASUREMENTS` rounds: a node's spread is its tightest window of
  :data:`AGREEING` times' max/min − 1, its time the least of its times (other work on the machine
  only ever adds time: the least is the least disturbed);
* two nodes whose times differ by less than their spreads added (at least :data:`AGREEMENT`) get
  one speed: the panel shows a node's speed only where the speeds differ.

Pure bookkeeping: the service sends the messages and passes the clock and the times in.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from tessera.balancers.hetero import calibration_region
from tessera.geometry import Camera
from tessera.wire.messages import Calibrate

#: Renders of the region per measurement; the node reports the fastest.
CALIBRATION_REPEATS = 3
CALIBRATION_TIMEOUT_S = 30.0
#: A node's last this many times must agree.
AGREEING = 3
#: ... within this fraction (max/min − 1); also the least difference between two speeds shown apart.
AGREEMENT = 0.10
#: A node whose times do not agree by then keeps the tightest window it had, and its spread says so.
MAX_MEASUREMENTS = 8
#: Measurements that failed or timed out before a node is left with the speed it has.
MAX_FAILURES = 2
#: Longest wait of a measurement for the nodes to finish the frames they draw (s).
QUIET_WAIT_S = 5.0


def calibrate_message(camera: Camera, size: tuple[int, int], scene: str | None = None,
                      lod_error_px: float | None = None) -> Calibrate:
    """Calibrate on ``scene`` (the default session's: every node loads it) at ``size``, at the levels
    of detail within ``lod_error_px`` pixels (None: full detail)."""
    return Calibrate(camera=camera, size=size, rect=calibration_region(size), repeats=CALIBRATION_REPEATS,
                     scene=scene, lod_error_px=lod_error_px)


@dataclass(frozen=True)
class NodeTime:
    """A node's calibration: ``ms`` its time, ``spread`` how far its agreeing times lie apart
    (max/min − 1), of ``measurements`` in all."""

    ms: float
    spread: float
    measurements: int


def node_time(times_ms: Sequence[float]) -> NodeTime | None:
    """The least time, and the spread of the tightest window of :data:`AGREEING` consecutive times
    (all of them when fewer); None without a time."""
    if not times_ms:
        return None
    width = min(AGREEING, len(times_ms))
    windows = [times_ms[i:i + width] for i in range(len(times_ms) - width + 1)]
    tightest = min(windows, key=lambda window: max(window) / min(window))
    return NodeTime(min(times_ms), max(tightest) / min(tightest) - 1.0, len(times_ms))


@dataclass(frozen=True)
class NodeSpeed:
    """``speed``: Pᵢ (slowest = 1); ``spread``: the node's own; ``distinct``: the nodes' speeds differ
    beyond their spreads (else every node has speed 1)."""

    speed: float
    spread: float
    distinct: bool


def node_speeds(times: Mapping[int, NodeTime]) -> dict[int, NodeSpeed]:
    """Pᵢ = t_max / tᵢ over groups of nodes: from the fastest, a node joins the group of the one
    before when its time is within (1 + tolerance) × the group's first, the tolerance being the two
    nodes' spreads added (at least :data:`AGREEMENT`); a group's time is its members' median."""
    groups: list[list[int]] = []
    for node in sorted(times, key=lambda n: times[n].ms):
        if groups:
            first = times[groups[-1][0]]
            if times[node].ms <= first.ms * (1.0 + max(AGREEMENT, first.spread + times[node].spread)):
                groups[-1].append(node)
                continue
        groups.append([node])
    group_ms = [statistics.median(times[n].ms for n in group) for group in groups]
    slowest = max(group_ms, default=0.0)
    return {node: NodeSpeed(slowest / ms, times[node].spread, len(groups) > 1)
            for group, ms in zip(groups, group_ms, strict=True) for node in group}


class CalibrationRounds:
    """Which node is measured next, one at a time, in rounds, until every node's times agree; a node
    that does not answer within :data:`CALIBRATION_TIMEOUT_S` counts a failure."""

    def __init__(self) -> None:
        self.times: dict[int, list[float]] = {}
        self.failures: dict[int, int] = {}
        self.current: int | None = None
        self.started_at = 0.0
        #: Since when a measurement waits for the cluster to be quiet (None: none waits).
        self.waiting_since: float | None = None
        #: Times came in since :meth:`take_speeds` last answered.
        self._fresh = False
        #: Per node, the measurements given up on (timed out) whose answers may still come: dropped.
        self.late: dict[int, int] = {}

    def request(self, node_id: int) -> None:
        """Measure ``node_id``, and every node known, again from the start."""
        for node in [*self.times, node_id]:
            self.times[node] = []
            self.failures[node] = 0

    def forget(self, node_id: int) -> None:
        self.times.pop(node_id, None)
        self.failures.pop(node_id, None)
        self.late.pop(node_id, None)
        if self.current == node_id:
            self.current = None
        self._fresh = True

    def measured(self, node_id: int, ms: float) -> bool:
        """The time ``node_id`` reported; False when it was not the node being measured (nor
        answers a measurement that timed out: that answer is dropped)."""
        if self.current != node_id:
            return self._late_answer(node_id)
        self.current = None
        self.times[node_id].append(float(ms))
        self._fresh = True
        return True

    def failed(self, node_id: int) -> bool:
        """``node_id``'s measurement failed; False when it was not the node being measured (nor
        answers a measurement that timed out)."""
        if self.current != node_id:
            return self._late_answer(node_id)
        self.current = None
        self.failures[node_id] += 1
        return True

    def _late_answer(self, node_id: int) -> bool:
        """An answer of a node not being measured is to a measurement that timed out (a node busy
        with a long tile answers late): counted off, nothing recorded. (The node being measured
        answers for this measurement whichever request it answers: a time is its time.)"""
        if not self.late.get(node_id):
            return False
        self.late[node_id] -= 1
        return True

    def left_out(self, node_id: int) -> bool:
        """The node failed too often: it keeps the speed it has."""
        return self.failures[node_id] >= MAX_FAILURES

    def agrees(self, node_id: int) -> bool:
        """The node's last :data:`AGREEING` times agree within :data:`AGREEMENT`."""
        times = self.times[node_id][-AGREEING:]
        return len(times) == AGREEING and max(times) / min(times) - 1.0 <= AGREEMENT

    def finished(self) -> bool:
        """Every node (but those left out) was measured as often as the others, and either every
        node's times agree or :data:`MAX_MEASUREMENTS` rounds are done."""
        counts = {len(self.times[node]) for node in self.times if not self.left_out(node)}
        if len(counts) > 1:
            return False
        rounds = counts.pop() if counts else MAX_MEASUREMENTS
        return rounds >= MAX_MEASUREMENTS or all(self.agrees(node) or self.left_out(node) for node in self.times)

    def next_to_start(self, now: float, busy: bool = False, jobs_only: bool = False) -> int | None:
        """The node to measure now, if none is being measured (or the one being measured timed out);
        ``busy``: nodes are drawing frames, so it waits (at most :data:`QUIET_WAIT_S`; with
        ``jobs_only``, nothing but render jobs' tiles: as long as they draw)."""
        if self.current is not None:
            if now - self.started_at < CALIBRATION_TIMEOUT_S:
                return None
            timed_out = self.current
            self.failed(timed_out)
            self.late[timed_out] = self.late.get(timed_out, 0) + 1
        if self.finished():
            self.waiting_since = None
            return None
        waiting = [node for node in self.times if not self.left_out(node)]
        if busy:
            self.waiting_since = now if self.waiting_since is None else self.waiting_since
            if jobs_only or now - self.waiting_since < QUIET_WAIT_S:
                return None
        self.waiting_since = None
        self.current = min(waiting, key=lambda node: len(self.times[node]) + self.failures[node])
        self.started_at = now
        return self.current

    def take_speeds(self) -> tuple[dict[int, NodeTime], dict[int, NodeSpeed]] | None:
        """Every node's time and speed once the rounds are :meth:`finished` and times came in since
        the last answer; else None."""
        if not self._fresh or self.current is not None or not self.finished():
            return None
        self._fresh = False
        times = {node: time for node, ms in self.times.items() if (time := node_time(ms)) is not None}
        return times, node_speeds(times)
