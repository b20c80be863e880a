"""``python -m bench.stream`` end to end on a small run (a real coordinator and node, a viewer that
decodes tiles and video with PyAV, through a throttled loopback link, resting for the still);
speeds are reported, never asserted: only that the figures exist and make sense."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bench.paths import orbit_around
from bench.stream import TRANSPORTS, PathPlayer, main
from bench.stream_summary import summarize, summary_table
from tessera.geometry import Camera

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


def test_orbit_around_a_camera_turns_its_eye_about_its_target_at_its_height_and_distance():
    camera = Camera(eye=(3.0, 2.0, 1.0), target=(1.0, 0.5, -1.0), fovy_deg=37.0)
    path = orbit_around(camera, frames=8)
    eyes = np.array([frame["eye"] for frame in path["frames"]])
    assert path["frames"][0]["eye"] == pytest.approx(list(camera.eye))
    assert all(frame["target"] == pytest.approx(list(camera.target)) and frame["fovy_deg"] == 37.0
               for frame in path["frames"])
    offsets = eyes - np.asarray(camera.target)
    assert offsets[:, 1] == pytest.approx([1.5] * 8)
    assert np.hypot(offsets[:, 0], offsets[:, 2]) == pytest.approx([math.hypot(2.0, 2.0)] * 8)
    assert eyes[4] - np.asarray(camera.target) == pytest.approx([-2.0, 1.5, -2.0]), "half a turn: the other side"


def _run(size: list[int], camera: str, tiles: tuple[float, float], h264: tuple[float, float]) -> dict:
    """A run whose tiles and H.264 rows have (psnr_mean, wire bytes a frame)."""
    def row(psnr: float, wire: float) -> dict:
        return {"fps": 10.0, "psnr_mean": psnr, "wire_bytes_per_frame": wire, "bytes_per_frame": 2 * wire}
    return {"size": size, "camera": camera, "transports": {"tiles": row(*tiles), "h264": row(*h264)}}


def test_the_summary_puts_the_worst_run_beside_the_mean():
    runs = [_run([64, 36], "camera 0", (40.0, 9000.0), (40.5, 3000.0)),
            _run([64, 36], "camera 1", (42.0, 8000.0), (41.0, 4000.0)),
            _run([64, 36], "camera 2", (38.0, 10000.0), (38.2, 2000.0))]
    summary = summarize(runs)
    h264 = summary["h264"]
    assert h264["runs"] == 3 and h264["psnr_mean"] == pytest.approx((40.5 + 41.0 + 38.2) / 3, abs=1e-3)
    assert h264["psnr_worst"] == 38.2 and h264["psnr_worst_run"] == "64x36 camera 2"
    assert h264["vs_tiles_db_worst"] == pytest.approx(-1.0) and h264["vs_tiles_db_worst_run"] == "64x36 camera 1"
    assert h264["vs_tiles_db_mean"] == pytest.approx((0.5 - 1.0 + 0.2) / 3, abs=1e-3)
    assert h264["wire_ratio_worst"] == 0.5 and h264["wire_ratio_worst_run"] == "64x36 camera 1"
    assert h264["message_ratio_mean"] == pytest.approx(h264["wire_ratio_mean"])
    assert "vs_tiles_db_mean" not in summary["tiles"] and summary["tiles"]["psnr_worst"] == 38.0
    assert any("64x36 camera 1" in line for line in summary_table({"64x36": summary}))


@pytest.mark.integration
@pytest.mark.gl
def test_stream_bench_over_random_cameras_and_sizes(tmp_path):
    out = tmp_path / "stream.json"
    assert main(["--nodes", "1", "--sizes", "160x90,192x108", "--cameras", "2", "--transports", "tiles,h264",
                 "--moving-s", "2.5", "--psnr-frames", "2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert [(run["size"], run["camera"]) for run in result["runs"]] == [
        ([160, 90], "camera 0"), ([160, 90], "camera 1"), ([192, 108], "camera 0"), ([192, 108], "camera 1")]
    for run in result["runs"]:
        assert run["transports"]["h264"]["decoded_size"] == [run["size"]], run
        assert run["transports"]["h264"]["crf"] is not None, run
    assert set(result["summary"]) == {"160x90", "192x108"}
    for summary in (result, *result["summary"].values()):
        h264 = summary["h264"]
        assert h264["psnr_worst"] <= h264["psnr_mean"] and h264["vs_tiles_db_worst"] <= h264["vs_tiles_db_mean"]
        assert h264["wire_ratio_worst"] >= h264["wire_ratio_mean"] > 0
    assert result["h264"]["runs"] == 4 and result["run"]["cameras"] == 2
