"""bench.points' report: ingest figures only of a cache build, never of a cache that held the cloud."""

from __future__ import annotations

from bench.points import report


def result(read_s: float | None) -> dict:
    built = read_s is not None
    ingest = {"points": 10_000_000, "wall_s": 2.0, "read_s": read_s, "cpu_s": 4.0, "peak_mb": 900.0, "nodes": 640,
              "load": 1.0, "built": built, "points_per_s": 5e6 if built else None,
              "points_per_cpu_s": 2.5e6 if built else None}
    return {"cloud": "terrain.laz", "bytes": 66e6, "nodes": 3, "size": [1280, 720], "runs": [], "ingest": ingest}


def test_a_cache_hit_reports_no_ingest_rate_and_a_build_does():
    assert "ingest: none, the cache held the cloud" in report(result(None))
    assert "M points/s" not in report(result(None))
    assert "ingest: 5.00 M points/s" in report(result(0.7))
