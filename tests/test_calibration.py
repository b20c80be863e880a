"""Calibration bookkeeping (seed 003 §1): speeds from times, one node at a time, timeouts."""

from __future__ import annotations

from server.calibration import CALIBRATION_TIMEOUT_S, CalibrationQueue, central_region, speeds_from_times
from tessera.geometry import Rect


def test_speeds_are_slowest_time_over_own_time():
    assert speeds_from_times({1: 10.0, 2: 20.0, 3: 40.0}) == {1: 4.0, 2: 2.0, 3: 1.0}
    assert speeds_from_times({1: 0.0, 2: 5.0}) == {2: 1.0}
    assert speeds_from_times({}) == {}


def test_central_region_is_the_middle_half():
    assert central_region((640, 480)) == Rect(160, 120, 320, 240)


def test_queue_runs_one_node_at_a_time_and_skips_a_silent_one():
    queue = CalibrationQueue()
    for node in (1, 2, 2, 3):
        queue.request(node)
    assert queue.next_to_start(0.0) == 1
    assert queue.next_to_start(1.0) is None, "one at a time"
    assert not queue.finished(2), "only the node calibrating may answer"
    assert queue.finished(1)
    assert queue.next_to_start(2.0) == 2
    assert queue.next_to_start(2.0 + CALIBRATION_TIMEOUT_S) == 3, "a silent node is skipped"
    queue.forget(3)
    assert queue.next_to_start(100.0) is None
    assert queue.current is None


def test_forgetting_the_calibrating_node_lets_the_next_start():
    queue = CalibrationQueue()
    queue.request(1)
    queue.request(2)
    assert queue.next_to_start(0.0) == 1
    queue.forget(1)
    assert queue.next_to_start(0.5) == 2
    queue.forget(2)
    assert queue.current is None and not queue.waiting
