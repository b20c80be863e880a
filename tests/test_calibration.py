"""Calibration bookkeeping (seed 003 §1): speeds from times, one node at a time, timeouts."""

from __future__ import annotations

from server.calibration import CALIBRATION_TIMEOUT_S, CalibrationQueue


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
