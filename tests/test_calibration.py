"""Calibration bookkeeping (seed 003 §1; issue 38's speeds a user can believe): one node at a time,
in rounds, each node measured until its times agree (or it reports their spread), every node again
when one joins, nodes within each other's spread at one speed, timeouts and failures."""

from __future__ import annotations

import pytest

from server.calibration import (
    AGREEING,
    AGREEMENT,
    CALIBRATION_TIMEOUT_S,
    MAX_FAILURES,
    MAX_MEASUREMENTS,
    QUIET_WAIT_S,
    CalibrationRounds,
    NodeTime,
    node_speeds,
    node_time,
)


def run(rounds: CalibrationRounds, times: dict[int, list[float]], now: float = 0.0) -> list[int]:
    """Answer every measurement the rounds ask for with the next of ``times[node]``; the order asked."""
    asked = []
    while (node := rounds.next_to_start(now)) is not None:
        asked.append(node)
        assert rounds.next_to_start(now) is None, "one at a time"
        assert rounds.measured(node, times[node].pop(0))
    return asked


def test_nodes_are_measured_in_rounds_until_every_nodes_times_agree():
    rounds = CalibrationRounds()
    rounds.request(1)
    rounds.request(2)
    noisy = [30.0, 10.0, 20.0, 11.0, 10.5, 10.2, 10.1]   # settles on its last three
    asked = run(rounds, {1: [10.0] * 8, 2: list(noisy)})
    assert asked == [1, 2] * 6, "rounds of one measurement each, until every node's times agree"
    times, speeds = rounds.take_speeds()
    assert times[2] == NodeTime(ms=10.0, spread=pytest.approx(11.0 / 10.2 - 1), measurements=6), "the least time"
    assert times[1] == NodeTime(10.0, 0.0, 6)
    assert {node: speed.speed for node, speed in speeds.items()} == {1: 1.0, 2: 1.0}, "the same, within spread"
    assert not any(speed.distinct for speed in speeds.values())
    assert rounds.take_speeds() is None, "nothing new"


def test_times_that_never_agree_stop_at_the_most_measurements_and_report_their_spread():
    rounds = CalibrationRounds()
    rounds.request(1)
    wild = [10.0, 30.0, 11.5, 10.2, 11.7, 30.0, 10.0, 50.0, 99.0]
    assert run(rounds, {1: wild}) == [1] * MAX_MEASUREMENTS
    times, _ = rounds.take_speeds()
    assert times[1].measurements == MAX_MEASUREMENTS
    assert times[1].spread == pytest.approx(11.7 / 10.2 - 1), "the tightest window"
    assert times[1].ms == 10.0


def test_a_node_joining_measures_every_node_again():
    rounds = CalibrationRounds()
    rounds.request(1)
    run(rounds, {1: [30.0, 30.0, 30.0]})   # measured while the second node loaded its scene
    rounds.take_speeds()
    rounds.request(2)
    assert run(rounds, {1: [10.0] * 3, 2: [10.0] * 3}) == [1, 2] * AGREEING
    times, speeds = rounds.take_speeds()
    assert times[1].ms == 10.0 and speeds[1].speed == speeds[2].speed == 1.0


def test_speeds_differ_only_beyond_the_spread():
    def timed(ms: float, spread: float = 0.0) -> NodeTime:
        return NodeTime(ms, spread, AGREEING)

    same = node_speeds({1: timed(10.0), 2: timed(10.0 * (1 + AGREEMENT) - 0.01), 3: timed(10.5)})
    assert {s.speed for s in same.values()} == {1.0} and not any(s.distinct for s in same.values())
    slow = node_speeds({1: timed(10.0), 2: timed(10.4), 3: timed(30.6)})
    assert slow[3].speed == 1.0 and slow[1].speed == slow[2].speed == pytest.approx(30.6 / 10.2)
    assert all(s.distinct for s in slow.values())
    loose = node_speeds({1: timed(10.0, spread=0.3), 2: timed(14.0, spread=0.15)})
    assert loose[1].speed == loose[2].speed == 1.0, "within their spreads added: not told apart"
    apart = node_speeds({1: timed(10.0, spread=0.2), 2: timed(13.5, spread=0.1)})
    assert apart[1].speed == pytest.approx(1.35) and apart[1].distinct
    assert node_speeds({1: timed(10.0), 2: timed(12.0)})[1].speed == pytest.approx(1.2)
    assert node_time([]) is None


def test_a_silent_or_failing_node_is_left_after_its_failures_and_the_others_go_on():
    rounds = CalibrationRounds()
    rounds.request(1)
    rounds.request(2)
    assert rounds.next_to_start(0.0) == 1
    assert rounds.next_to_start(1.0) is None, "one at a time"
    assert not rounds.measured(2, 5.0), "only the node being measured may answer"
    assert rounds.next_to_start(CALIBRATION_TIMEOUT_S) == 2, "node 1 timed out: a failure"
    assert rounds.measured(2, 5.0)
    assert rounds.next_to_start(CALIBRATION_TIMEOUT_S) == 1
    assert not rounds.failed(2) and rounds.failed(1)
    assert MAX_FAILURES == 2 and rounds.left_out(1)
    assert run(rounds, {2: [5.0, 5.0]}, CALIBRATION_TIMEOUT_S) == [2, 2]
    times, speeds = rounds.take_speeds()
    assert set(times) == {2} and speeds[2].speed == 1.0


def test_a_late_answer_to_a_measurement_that_timed_out_is_dropped_not_a_protocol_error():
    rounds = CalibrationRounds()
    rounds.request(1)
    rounds.request(2)
    assert rounds.next_to_start(0.0) == 1
    assert rounds.next_to_start(CALIBRATION_TIMEOUT_S) == 2, "node 1 timed out (a long tile): a failure"
    assert rounds.measured(1, 50.0), "its late answer is expected, not an error"
    assert rounds.times[1] == [] and rounds.failures[1] == 1, "and recorded nowhere"
    assert not rounds.measured(1, 50.0), "a second one was never asked for"
    assert rounds.measured(2, 5.0) and rounds.times[2] == [5.0]


def test_forgetting_the_node_being_measured_lets_the_next_start():
    rounds = CalibrationRounds()
    rounds.request(1)
    rounds.request(2)
    assert rounds.next_to_start(0.0) == 1
    rounds.forget(1)
    assert rounds.next_to_start(0.5) == 2
    rounds.forget(2)
    assert rounds.current is None and not rounds.times


def test_a_measurement_waits_for_the_frames_being_drawn_but_not_for_ever():
    rounds = CalibrationRounds()
    rounds.request(1)
    assert rounds.next_to_start(0.0, busy=True) is None
    assert rounds.next_to_start(QUIET_WAIT_S / 2, busy=True) is None
    assert rounds.next_to_start(QUIET_WAIT_S / 2 + 0.1, busy=False) == 1, "quiet: at once"
    rounds.measured(1, 5.0)
    assert rounds.next_to_start(10.0, busy=True) is None
    assert rounds.next_to_start(10.0 + QUIET_WAIT_S, busy=True) == 1, "a cluster that never rests is measured too"


def test_a_measurement_waits_for_render_jobs_as_long_as_they_alone_draw():
    """Posters and films keep every node busy for minutes: a measurement beside them would be
    disturbed and hold up the measured node's job tiles, so it waits for them to end."""
    rounds = CalibrationRounds()
    rounds.request(1)
    assert rounds.next_to_start(0.0, busy=True, jobs_only=True) is None
    assert rounds.next_to_start(10 * QUIET_WAIT_S, busy=True, jobs_only=True) is None, "render jobs alone: it waits"
    assert rounds.next_to_start(10 * QUIET_WAIT_S + 0.1, busy=True) == 1, "a session's frames too: not for ever"
    rounds.measured(1, 5.0)
    rounds.request(1)
    assert rounds.next_to_start(20 * QUIET_WAIT_S, busy=True, jobs_only=True) is None
    assert rounds.next_to_start(20 * QUIET_WAIT_S + 0.1) == 1, "the job ended: at once"
