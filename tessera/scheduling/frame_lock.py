"""Frame lock of a display wall's cells (issue 22, seed 004: every display swaps together).

Deliver first, swap second: each cell viewer reports the newest frame it decoded and holds
(``have``); frame K is presented once every live cell holds K or newer (the lock point is the
oldest of their newest frames, so a cell that fell behind and jumped to the newest frame pulls the
lock forward rather than holding the others). A cell that reported nothing for ``stale_s`` is
left out until it reports again; a cell that joins (or comes back) once the others presented a
frame is told to present that frame alone as soon as it holds it. Each cell then says when it
presented the frame, on the coordinator's clock; the spread of those times over the cells is the
frame's present skew.

When: a present names a time (:meth:`FrameLock.due` sets ``at_ms``), the lead ahead of now, put
on the cells' refresh phase. The lead is the longest a present took to reach a cell and be shown,
over the last :data:`LEAD_WINDOW` presents (at least :data:`MIN_LEAD_MS`, at most
:data:`MAX_LEAD_MS`): a cell that showed a frame more than half a refresh after its time got the
message late. The phase is the circular mean of the reported present times modulo
:data:`REFRESH_MS` (cells report the start of the animation frame they swapped in, which is on
their display's refresh grid): a present time on that grid is half a refresh from the edges where
a cell picking "the animation frame nearest the time" (web/wall.js) could pick either of two,
so clock estimates a few ms apart still pick the same refresh.

Pure: clocks come in as arguments (s for ``now``, ms for present times).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass, field

import numpy as np

#: A cell that reported nothing for this long no longer holds the others back (s); cells ping
#: every half second (web/viewer.js), so a live one is never this quiet.
STALE_S = 2.5
#: Present skews kept for the percentiles (frames).
SKEW_WINDOW = 600
#: The cells' display refresh interval the present times are placed on (ms; 60 Hz).
REFRESH_MS = 1000.0 / 60.0
#: Shortest and longest time ahead of now a present names (ms): the message must reach every
#: cell (and get through a busy page's event loop) before then; the latency a wall adds.
MIN_LEAD_MS = 20.0
MAX_LEAD_MS = 100.0
#: Presents the lead is chosen over (the longest any of them needed).
LEAD_WINDOW = 60
#: Reported present times the refresh phase is estimated from.
PHASE_WINDOW = 64


@dataclass
class _Cell:
    newest: int = -1
    heard_at: float = 0.0
    told: int = -1


@dataclass
class _Presenting:
    """Frame ``frame`` was presented to ``cells`` at ``due_ms``, ``sent_ms`` being then; their
    present times (ms) as reported."""

    frame: int
    cells: frozenset[Hashable]
    due_ms: float
    sent_ms: float
    at_ms: dict[Hashable, float] = field(default_factory=dict)


class FrameLock:
    """The cells of one wall, each a viewer (any hashable key)."""

    def __init__(self, stale_s: float = STALE_S, window: int = SKEW_WINDOW) -> None:
        self.stale_s = stale_s
        self._cells: dict[Hashable, _Cell] = {}
        self.presented = -1
        #: Frames the lock presented (every live cell told at once).
        self.presents = 0
        self._presenting: _Presenting | None = None
        self.skews_ms: deque[float] = deque(maxlen=window)
        #: The time (the coordinator's ms) the cells :meth:`due` returned last are to present at.
        self.at_ms = 0.0
        #: The lead each recent present needed (ms), and the recent present times reported (ms).
        self._needed_ms: deque[float] = deque(maxlen=LEAD_WINDOW)
        self._reported_ms: deque[float] = deque(maxlen=PHASE_WINDOW)

    def join(self, cell: Hashable, now: float) -> None:
        self._cells[cell] = _Cell(heard_at=now)

    def leave(self, cell: Hashable) -> None:
        self._cells.pop(cell, None)

    def heard(self, cell: Hashable, now: float) -> None:
        """``cell`` said something (a ping): it is live."""
        if cell in self._cells:
            self._cells[cell].heard_at = now

    def have(self, cell: Hashable, frame_id: int, now: float) -> None:
        """``cell`` decoded frame ``frame_id`` and holds it."""
        state = self._cells.get(cell)
        if state is not None:
            state.newest, state.heard_at = max(state.newest, frame_id), now

    def due(self, now: float) -> dict[Hashable, int]:
        """The cells to tell to present, and which frame: every live cell the frame they all hold
        now, when newer than the one presented last (it counts as presented from here on); else a
        cell that holds the frame presented last but was not told it yet (it joined since)."""
        live = {key: c for key, c in self._cells.items() if now - c.heard_at <= self.stale_s}
        lock = min((c.newest for c in live.values()), default=-1)
        if lock > self.presented:
            self._finish()
            self.at_ms = self.present_time(now)
            self.presented, self.presents = lock, self.presents + 1
            self._presenting = _Presenting(lock, frozenset(live), self.at_ms, now * 1000.0)
            told = live
        else:
            told = {key: c for key, c in live.items() if c.told < self.presented <= c.newest}
            if told:
                self.at_ms = self.present_time(now)
        for cell in told.values():
            cell.told = self.presented
        return {key: self.presented for key in told}

    @property
    def lead_ms(self) -> float:
        """How far ahead of now a present names its time (ms): the most a recent present needed."""
        return min(MAX_LEAD_MS, max([MIN_LEAD_MS, *self._needed_ms]))

    @property
    def phase_ms(self) -> float | None:
        """Where the cells' refreshes start, modulo :data:`REFRESH_MS` (ms); None before any report."""
        if not self._reported_ms:
            return None
        angles = np.asarray(self._reported_ms) * (2.0 * np.pi / REFRESH_MS)
        mean = float(np.angle(np.exp(1j * angles).mean()))
        return (mean % (2.0 * np.pi)) * REFRESH_MS / (2.0 * np.pi)

    def present_time(self, now: float) -> float:
        """When a present told at ``now`` (s) is to be shown (the coordinator's ms): :attr:`lead_ms`
        ahead, then on to the next refresh start of the cells' phase."""
        at_ms = now * 1000.0 + self.lead_ms
        phase = self.phase_ms
        if phase is None:
            return at_ms
        return phase + REFRESH_MS * float(np.ceil((at_ms - phase) / REFRESH_MS))

    def report(self, cell: Hashable, frame_id: int, at_ms: float) -> None:
        """``cell`` put frame ``frame_id`` on screen at ``at_ms`` (the coordinator's clock)."""
        presenting = self._presenting
        if presenting is None or presenting.frame != frame_id or cell not in presenting.cells:
            return
        presenting.at_ms[cell] = at_ms
        self._reported_ms.append(at_ms)
        if len(presenting.at_ms) == len(presenting.cells):
            self._finish()

    def _finish(self) -> None:
        """The frame presenting now is done: its skew is kept when two cells or more reported."""
        presenting, self._presenting = self._presenting, None
        if presenting is None or not presenting.at_ms:
            return
        times = presenting.at_ms.values()
        if len(presenting.at_ms) >= 2:
            self.skews_ms.append(max(times) - min(times))
        # on time: within half a refresh of the due time; later, the message took till then (or nearly)
        late = max(times) > presenting.due_ms + REFRESH_MS / 2
        self._needed_ms.append(max(times) - presenting.sent_ms if late else MIN_LEAD_MS)

    def describe(self) -> dict[str, float | int | None]:
        """``skew_p50_ms``, ``skew_p99_ms`` (None before two cells presented a frame), ``skew_samples``,
        ``presented`` (the last frame presented, -1: none), ``presents`` (frames presented), ``cells``,
        ``lead_ms`` (how far ahead presents are told now)."""
        skews = np.asarray(self.skews_ms, dtype=np.float64)
        p50, p99 = (float(np.percentile(skews, q)) for q in (50, 99)) if skews.size else (None, None)
        return {"skew_p50_ms": None if p50 is None else round(p50, 3),
                "skew_p99_ms": None if p99 is None else round(p99, 3),
                "skew_samples": int(skews.size), "presented": self.presented, "presents": self.presents,
                "cells": len(self._cells), "lead_ms": round(self.lead_ms, 3)}
