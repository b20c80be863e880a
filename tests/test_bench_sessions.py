"""The sessions benchmark end to end (a real coordinator, real nodes, real viewers) on a small
run; speeds are reported, never asserted: only that the figures exist and make sense."""

from __future__ import annotations

import json
import math

import pytest

from bench.sessions import jain, main

pytestmark = [pytest.mark.integration, pytest.mark.gl]


def test_jains_index():
    assert jain([1.0, 1.0, 1.0]) == pytest.approx(1.0)
    assert jain([1.0, 0.0, 0.0, 0.0]) == pytest.approx(0.25)
    assert math.isnan(jain([0.0, 0.0]))


def test_sessions_bench_end_to_end(tmp_path):
    out = tmp_path / "sessions.json"
    assert main(["--nodes", "2", "--sessions", "2", "--size", "160x90", "--input-hz", "30", "--moving-s", "4",
                 "--idle-s", "2", "--large-scene", "builtin:cluster", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    sessions = result["per_session"]
    assert [s["session"] for s in sessions] == ["default", "1"]
    assert all(s["fps"] > 0 and s["latency_p50_ms"] > 0 for s in sessions), sessions
    assert sum(s["node_share"] for s in sessions) == pytest.approx(1.0, abs=0.01)
    assert 0.0 < result["jain_node_share"] <= 1.0 and result["node_busy_fraction"] > 0
    large = result["large_scene"]
    assert large["ready_s"] >= large["loaded_s"] > 0 and large["longest_gap_ms"] > 0
    assert not large["longest_gap_loading_ms"] > large["longest_gap_ms"], "the loading is part of the whole window"
    assert large["everywhere_s"] >= large["ready_s"], "every node holds it once the first does and more"
    assert not large["longest_gap_ms"] > large["longest_gap_everywhere_ms"], "the window until ready is part of it"
    assert result["idle_frames"] == 0, "idle sessions render nothing"
