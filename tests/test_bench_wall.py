"""The wall benchmark end to end (a real coordinator, real nodes, scripted cells and driver) on a
small run; speeds are reported, never asserted: only that the figures exist and make sense."""

from __future__ import annotations

import json

import pytest

from bench.wall import main, present_timing

pytestmark = [pytest.mark.integration, pytest.mark.gl]


def test_wall_bench_end_to_end(tmp_path):
    out = tmp_path / "wall.json"
    assert main(["--cols", "2", "--rows", "1", "--cell", "96x64", "--bezel", "4x0", "--nodes", "2",
                 "--scene", "builtin:spheres", "--moving-s", "3", "--rounds", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert len(result["rounds"]) == 2
    for phases in result["rounds"]:
        wall, single = phases["wall"], phases["single"]
        assert wall["size"] == [196, 64] and single["size"] == [196, 64]
        assert wall["presented_fps"] > 0 and wall["driver_fps"] > 0 and single["fps"] > 0
        assert wall["skew_samples"] >= 1 and 0.0 <= wall["skew_p50_ms"] <= wall["skew_p99_ms"]
        assert wall["lead_ms"] >= 20.0 and wall["present_timing"] is None   # scripted cells keep no page log
        for cores in (wall["cores"], single["cores"]):
            assert cores["coordinator"] > 0 and cores["nodes"] > 0 and cores["machine"] > 0
        assert phases["fps_ratio"] > 0
        assert all(ms["nodes"] > 0 and ms["coordinator"] > 0 for ms in phases["cpu_ms_per_frame"].values())
    assert result["fps_ratio"] > 0 and result["wall_fps"] > 0 and result["cells_are"] == "scripted"
    assert result["nodes_cpu_ratio"] > 0 and isinstance(result["coordinator_extra_ms"], float)


def test_present_timing_reads_the_pages_present_logs():
    def entry(frame, due, received, ts, offset):
        return {"frame": frame, "due": due, "received": received, "ts": ts, "callback": ts + 2.0, "offset": offset}

    # two cells whose clocks are 1000 ms apart; frame 2 lands a refresh later on the second
    logs = [[entry(1, 100.0, 60.0, 99.0, 1000.0), entry(2, 200.0, 150.0, 199.0, 1000.0)],
            [entry(1, 1100.0, 1070.0, 1100.0, 0.0), entry(2, 1200.0, 1210.0, 1216.0, 0.0),
             entry(9, 5.0, 1.0, 6.0, 0.0)]]   # a frame not every cell presented in the window: left out
    timing = present_timing(logs, {1, 2})
    assert timing["frames"] == 2
    assert timing["ts_spread"]["max"] == 17.0 and timing["ts_spread"]["p50"] == 9.0
    assert timing["received_before_due"]["max"] == 50.0 and timing["received_before_due"]["p50"] == 35.0
    assert timing["callback_after_ts"] == {"p50": 2.0, "p99": 2.0, "max": 2.0}
