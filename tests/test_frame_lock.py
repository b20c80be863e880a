"""The wall's frame lock (issue 22, seed 004), on a virtual clock: a frame is presented once
every live cell holds it; a cell that fell behind and jumped to the newest frame pulls the lock
forward; a silent cell stops holding the others; the present skew over cells; the time a present
names (the lead a late cell needed, the cells' refresh phase)."""

from __future__ import annotations

import pytest

from tessera.scheduling.frame_lock import LEAD_WINDOW, MIN_LEAD_MS, REFRESH_MS, FrameLock


def test_a_frame_is_presented_once_every_cell_holds_it():
    lock = FrameLock()
    for cell in "abc":
        lock.join(cell, 0.0)
    lock.have("a", 5, 0.01)
    lock.have("b", 5, 0.01)
    assert lock.due(0.01) == {}     # c holds nothing yet
    lock.have("c", 4, 0.02)
    assert lock.due(0.02) == {"a": 4, "b": 4, "c": 4}   # every cell holds 4 (a and b hold 5 too)
    assert lock.due(0.02) == {}     # presented once
    lock.have("c", 5, 0.03)
    assert lock.due(0.03) == {"a": 5, "b": 5, "c": 5}


def test_a_cell_that_fell_behind_skips_to_the_newest_frame():
    lock = FrameLock()
    for cell in "ab":
        lock.join(cell, 0.0)
    for frame in (1, 2, 3, 4):
        lock.have("a", frame, 0.01 * frame)
    lock.have("b", 4, 0.05)            # b never decoded 1-3: it jumped to the newest
    assert lock.due(0.05) == {"a": 4, "b": 4}


def test_a_silent_cell_stops_holding_the_others_and_rejoins_when_it_reports():
    lock = FrameLock(stale_s=1.0)
    for cell in "ab":
        lock.join(cell, 0.0)
    lock.have("a", 7, 0.5)
    assert lock.due(0.5) == {}
    assert lock.due(1.2) == {"a": 7}   # b said nothing for over 1 s
    lock.leave("b")
    lock.have("a", 8, 1.3)
    assert lock.due(1.3) == {"a": 8}
    lock.join("b", 2.0)                # reopened after frame 8 was presented
    assert lock.due(2.0) == {}
    lock.have("b", 8, 2.1)             # it holds the newest frame: it alone presents it
    assert lock.due(2.1) == {"b": 8}
    assert lock.due(2.1) == {}
    lock.have("a", 9, 2.2)
    assert lock.due(2.2) == {}         # b holds the others back again
    lock.have("b", 9, 2.3)
    assert lock.due(2.3) == {"a": 9, "b": 9}


def test_skew_is_the_spread_of_present_times_over_the_cells():
    lock = FrameLock()
    for cell in "abc":
        lock.join(cell, 0.0)
    for frame, spreads in enumerate(([0.0, 1.0, 3.0], [0.0, 0.5, 0.5], [2.0, 0.0, 0.0]), start=1):
        for cell in "abc":
            lock.have(cell, frame, frame)
        assert set(lock.due(frame).values()) == {frame}
        for cell, offset in zip("abc", spreads, strict=True):
            lock.report(cell, frame, 1000.0 * frame + offset)
    lock.report("a", 1, 5000.0)         # a frame already finished: ignored
    figures = lock.describe()
    assert figures["skew_samples"] == 3
    assert figures["skew_p50_ms"] == 2.0
    assert 2.0 < figures["skew_p99_ms"] <= 3.0
    assert figures["presented"] == 3 and figures["presents"] == 3 and figures["cells"] == 3


def test_no_skew_before_two_cells_report():
    lock = FrameLock()
    lock.join("a", 0.0)
    lock.have("a", 1, 0.0)
    assert lock.due(0.0) == {"a": 1}
    lock.report("a", 1, 10.0)
    assert lock.describe()["skew_p50_ms"] is None


def present_all(lock: FrameLock, frame: int, now: float, late_ms: dict[str, float]) -> float:
    """Every cell holds ``frame`` at ``now`` (s) and reports it shown ``late_ms`` after the lock's
    time for it; returns that time (ms)."""
    for cell in late_ms:
        lock.have(cell, frame, now)
    assert set(lock.due(now).values()) == {frame}
    for cell, late in late_ms.items():
        lock.report(cell, frame, lock.at_ms + late)
    return lock.at_ms


def test_presents_are_told_the_shortest_lead_ahead_until_a_cell_shows_one_late():
    lock = FrameLock()
    for cell in "ab":
        lock.join(cell, 0.0)
    assert lock.describe()["lead_ms"] == MIN_LEAD_MS
    at = present_all(lock, 1, 1.0, {"a": 0.0, "b": 0.0})
    assert at == pytest.approx(1000.0 + MIN_LEAD_MS), "no report yet: no phase, the lead alone"
    present_all(lock, 2, 2.0, {"a": 0.0, "b": REFRESH_MS / 3})   # within half a refresh: on time
    assert lock.lead_ms == MIN_LEAD_MS
    present_all(lock, 3, 3.0, {"a": 0.0, "b": 45.0})              # b got it late
    at = present_all(lock, 4, 4.0, {"a": 0.0, "b": 0.0})          # frame 3 finishes when 4 is told
    assert lock.lead_ms == pytest.approx(45.0 + MIN_LEAD_MS + (lock.at_ms - at), abs=REFRESH_MS)
    assert at >= 4000.0 + 45.0 + MIN_LEAD_MS, "the next present is told as far ahead as b needed"
    for frame in range(5, 5 + LEAD_WINDOW + 1):
        present_all(lock, frame, float(frame), {"a": 0.0, "b": 0.0})
    assert lock.lead_ms == MIN_LEAD_MS, "once the late present left the window"


def test_present_times_fall_on_the_cells_refresh_phase():
    lock = FrameLock()
    for cell in "ab":
        lock.join(cell, 0.0)
    lock.have("a", 1, 1.0)
    lock.have("b", 1, 1.0)
    lock.due(1.0)
    edge = REFRESH_MS * round(lock.at_ms / REFRESH_MS)   # on time; both cells' refreshes start at 5 ms (mod 16.7)
    lock.report("a", 1, edge + 5.0)
    lock.report("b", 1, edge + 5.5)
    assert lock.lead_ms == MIN_LEAD_MS
    assert lock.phase_ms == pytest.approx(5.25)
    for now in (2.0, 2.0031, 2.0117):
        at = lock.present_time(now)
        assert now * 1000.0 + MIN_LEAD_MS <= at < now * 1000.0 + MIN_LEAD_MS + REFRESH_MS
        assert (at - 5.25) / REFRESH_MS == pytest.approx(round((at - 5.25) / REFRESH_MS))
    lock.report("a", 1, 16.0)   # a frame already finished: ignored, the phase stays
    assert lock.phase_ms == pytest.approx(5.25)


def test_the_phase_is_a_circular_mean_across_the_refresh_edge():
    lock = FrameLock()
    for cell in "ab":
        lock.join(cell, 0.0)
        lock.have(cell, 1, 0.0)
    lock.due(0.0)
    lock.report("a", 1, 16.0 * REFRESH_MS - 1.0)   # 1 ms before an edge
    lock.report("b", 1, 17.0 * REFRESH_MS + 1.0)   # 1 ms after one
    assert min(lock.phase_ms, REFRESH_MS - lock.phase_ms) == pytest.approx(0.0, abs=1e-6)
