"""Speeds a user can believe (issue 38), with real local nodes: two identical nodes and one three
times slower (``--node-slowdowns 1,1,3``, which scales a node's measured times). Every node is
measured until its times agree; the two identical nodes get one speed, the slow one 1 and a speed
told apart from theirs, each with the spread of its measurements. On a quiet machine (every node's
times agree, and the slow node's are three times the others': nothing else disturbed them) the
identical nodes must show one speed; on a busy one, they may be told apart only by more than their
spreads."""

from __future__ import annotations

import httpx
import pytest

from server.calibration import AGREEMENT, MAX_MEASUREMENTS
from tests.conftest import seconds
from tests.integration_support import stats, wait_ready_nodes, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl]


def test_identical_nodes_share_a_speed_and_a_slow_one_is_told_apart(coordinator_factory):
    coordinator = coordinator_factory("--scene", "builtin:cluster", "--size", "320x240", "--local-nodes", "3",
                                      "--node-slowdowns", "1,1,3")
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        wait_ready_nodes(client, 3)
        nodes = wait_until(lambda: (found := stats(client)["nodes"]) and all(n["calibration_ms"] for n in found)
                           and found, seconds(180), "every node calibrated", interval=0.5)
    slow = next(n for n in nodes if n["slowdown"] == 3.0)
    fast = [n for n in nodes if n is not slow]
    summary = [(n["name"], n["calibration_ms"], n["calibration_spread"], n["calibration_measurements"], n["speed"])
               for n in nodes]
    print("calibration (name, ms, spread, measurements, speed):", summary)
    for node in nodes:
        assert 1 <= node["calibration_measurements"] <= MAX_MEASUREMENTS
        assert node["calibration_spread"] is not None and node["calibration_spread"] >= 0
    assert slow["speed"] == 1.0 and slow["speed_distinct"], summary
    assert all(n["speed"] > 1.5 for n in fast), f"three times slower: told apart whatever the load: {summary}"
    spreads = [n["calibration_spread"] for n in fast]
    # The slow node is a yardstick: undisturbed, its times are exactly three times a fast node's. Each
    # fast node within AGREEMENT / (2 + AGREEMENT) of it puts the two within AGREEMENT of each other.
    ratios = [slow["calibration_ms"] / n["calibration_ms"] / 3.0 - 1.0 for n in fast]
    quiet = (max(n["calibration_spread"] for n in nodes) <= AGREEMENT
             and max(map(abs, ratios)) <= AGREEMENT / (2.0 + AGREEMENT))
    if quiet:
        assert fast[0]["speed"] == fast[1]["speed"], f"identical nodes on a quiet machine, one speed: {summary}"
    else:   # other work on the machine: told apart only beyond the spreads the panel shows
        apart = max(n["calibration_ms"] for n in fast) / min(n["calibration_ms"] for n in fast) - 1
        assert fast[0]["speed"] == fast[1]["speed"] or apart > max(AGREEMENT, sum(spreads)), summary
