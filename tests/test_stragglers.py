"""A node that stops answering without closing its socket (SIGSTOP) and a tile a node cannot render,
on a real coordinator with real local nodes: frames keep coming from the others, and the frozen
node takes part again once it answers (SIGCONT)."""

from __future__ import annotations

import os
import signal

import httpx
import pytest

from bench.processes import process_tree
from tests.conftest import seconds
from tests.integration_support import camera_moving, ready_nodes, stats, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl]


def test_a_frozen_node_is_worked_around_and_rejoins(coordinator_factory):
    coordinator = coordinator_factory("--scene", "builtin:cluster", "--size", "320x180", "--local-nodes", "3")
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        wait_until(lambda: len(ready_nodes(client)) == 3, seconds(120), "3 ready nodes")
        camera = client.get("/api/camera").json()["camera"]
        nodes = [pid for pid in process_tree(coordinator.proc.process.pid) if pid != coordinator.proc.process.pid]
        assert len(nodes) == 3, nodes
        with camera_moving(coordinator.url, camera):
            wait_until(lambda: all(n["tiles_rendered"] > 0 for n in stats(client)["nodes"]), seconds(60),
                       "every node rendering")
            os.kill(nodes[0], signal.SIGSTOP)
            try:
                frozen = wait_until(lambda: next((n for n in stats(client)["nodes"] if n["suspect"]), None),
                                    seconds(30), "the frozen node to be suspected")
                start = stats(client)["frame"]
                wait_until(lambda: stats(client)["frame"] >= start + 10, seconds(30),
                           "10 frames from the two nodes left")
                assert stats(client)["frames_in_flight"] <= 2
            finally:
                os.kill(nodes[0], signal.SIGCONT)
            rendered = frozen["tiles_rendered"]
            wait_until(lambda: any(n["name"] == frozen["name"] and not n["suspect"] and n["tiles_rendered"] > rendered
                                   for n in stats(client)["nodes"]), seconds(60),
                       "the thawed node to render again")
