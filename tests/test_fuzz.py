"""Hostile input at volume: at least 10,000 malformed messages across ``/ws/node`` (before and after the
hello, and from nodes given real tiles), ``/ws/view`` and the REST API, from the seeded generator of
``bench.hostile`` (the same code as ``python -m bench.hostile``), while two real local nodes keep
rendering. The coordinator must answer every one with a 4xx or a close with a reason, never crash,
log no traceback nor answer a 5xx, publish only frames equal to ``--render-once``, and give its
memory back.

A failure replays with the same seed: ``TESSERA_FUZZ_SEED`` (default 12) and ``TESSERA_FUZZ_MESSAGES``.
"""

from __future__ import annotations

import os

import httpx
import pytest

from bench.hostile import References, report, run_storm, shortfalls
from tests.conftest import seconds
from tests.integration_support import wait_ready_nodes

pytestmark = [pytest.mark.integration, pytest.mark.gl, pytest.mark.timeout(seconds(300))]

SCENE, SIZE, NODES, TOKEN = "builtin:spheres", (160, 120), 2, "fuzz-token"
SEED = int(os.environ.get("TESSERA_FUZZ_SEED", "12"))
MESSAGES = int(os.environ.get("TESSERA_FUZZ_MESSAGES", "10000"))


def test_ten_thousand_hostile_messages_leave_the_coordinator_serving_exact_frames(coordinator_factory):
    coordinator = coordinator_factory("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--codec", "png",
                                      "--still-samples", "1", "--local-nodes", str(NODES), "--token", TOKEN)
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30),
                      headers={"Authorization": f"Bearer {TOKEN}"}) as client:
        wait_ready_nodes(client, NODES, timeout_s=90)
        bounds = client.get("/api/camera").json()["bounds"]
    references = References.render(SCENE, bounds, SIZE)

    figures = run_storm(coordinator.url, TOKEN, MESSAGES, SEED, references, coordinator.proc.process.pid, NODES)
    figures.update(seed=SEED, crashed=coordinator.proc.process.poll() is not None,
                   tracebacks=coordinator.proc.tracebacks)
    print(report(figures))

    assert figures["messages"] >= MESSAGES and min(figures["sent"].values()) > 0.1 * MESSAGES
    assert figures["owed_sessions"] >= 10, "nodes given real tiles answered them wrongly"
    assert figures["frames_checked"] >= 20, "frames kept coming while the storm lasted"
    missed = shortfalls(figures, MESSAGES)
    assert not missed, "\n".join(missed + coordinator.proc.first_traceback)
