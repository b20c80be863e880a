"""``python -m bench.stream`` end to end on a small run (a real coordinator and node, a viewer that
decodes tiles and video with PyAV, through a throttled loopback link, resting for the still);
speeds are reported, never asserted: only that the figures exist and make sense."""

from __future__ import annotations

import json

import pytest

from bench.stream import TRANSPORTS, PathPlayer, main

KEYS = ("bytes_per_frame", "wire_bytes_per_frame", "mbps", "fps", "psnr_mean", "psnr_min", "encode_ms",
        "latency_intervals_p50")


def test_path_player_interpolates_between_frames_and_loops():
    frames = [{"eye": [0.0, 0.0, 1.0], "target": [0.0, 0.0, 0.0], "fovy_deg": 40.0},
              {"eye": [2.0, 0.0, 1.0], "target": [0.0, 0.0, 0.0], "fovy_deg": 50.0}]
    player = PathPlayer({"dt_ms": 100.0, "frames": frames})
    assert player.at(0.05)["eye"] == pytest.approx([1.0, 0.0, 1.0])
    assert player.at(0.05)["fovy_deg"] == pytest.approx(45.0)
    assert player.at(0.15)["eye"] == pytest.approx([1.0, 0.0, 1.0]), "from the last frame back to the first"
    assert player.at(0.2)["eye"] == pytest.approx([0.0, 0.0, 1.0])


@pytest.mark.integration
@pytest.mark.gl
def test_stream_bench_end_to_end(tmp_path):
    out = tmp_path / "stream.json"
    assert main(["--nodes", "1", "--size", "192x108", "--moving-s", "4", "--psnr-frames", "2",
                 "--throttle-mbps", "2", "--rest-s", "20", "--resume-s", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    for transport in TRANSPORTS:
        row = result[transport]
        assert row["transport"] == transport, row
        assert all(key in row for key in KEYS), row
        assert row["frames"] > 0 and row["fps"] > 0 and row["bytes_per_frame"] > 0 and row["mbps"] > 0, row
        assert 0 < row["wire_bytes_per_frame"] < 2 * row["bytes_per_frame"], row
        assert 1 <= row["psnr_frames"] <= 2 and row["psnr_min"] <= row["psnr_mean"], row
        # a frame of another camera than its input number names would be far below this
        assert row["psnr_min"] > 25.0, row
        assert row["latency_intervals_p50"] > 0 and row["latency_samples"] > 0, row
        assert row["decoded_size"] == [[192, 108]], row
        # through the throttled link the still arrives, equal to the coordinator's and to render-once's
        assert row["still_exact"] is True and row["still_psnr"] == 100.0 and row["still_s"] > 0, row
        assert row["fps_resumed"] > 0 and row["resume_ms"] > 0, row
    assert result["tiles"]["encode_ms"] is None and result["tiles"]["psnr_source_mean"] == 100.0
    for codec in TRANSPORTS[1:]:
        row = result[codec]
        assert row["encode_ms"] > 0 and row["frames_encoded"] >= row["frames"], row
        assert row["keyframes"] >= 1 and row["frames_lost"] == 0, row
