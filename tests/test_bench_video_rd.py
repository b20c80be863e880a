"""``python -m bench.video_rd``: its wire sizes are websockets' own, its interpolation, and a small
run end to end (real EGL rendering, the coordinator's H.264 encoder, PyAV decoding)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from websockets.extensions.permessage_deflate import PerMessageDeflate
from websockets.frames import Frame, Opcode

from bench.paths import orbit_around, random_cameras
from bench.stream import References
from bench.video_rd import bytes_at, deflated_sizes, loop_figures, main
from node.scene.loading import load_scene
from tessera.video.quality_control import CRF_RANGE


def test_wire_sizes_are_what_websockets_permessage_deflate_sends():
    rng = np.random.default_rng(1)
    block = bytes(rng.integers(0, 256, 2000, dtype=np.uint8))
    messages = [block, bytes(rng.integers(0, 4, 1000, dtype=np.uint8)), b"\x00" * 500, block]
    extension = PerMessageDeflate(False, False, 12, 12, {"memLevel": 5})
    sent = [len(extension.encode(Frame(Opcode.BINARY, m)).data) for m in messages]
    assert deflated_sizes(messages) == sent
    assert sent[3] < sent[0] / 4, "the window is kept from one message to the next"


def test_bytes_are_interpolated_log_linearly_in_psnr_and_extrapolated_beyond():
    points = [(40.0, 1000.0), (44.0, 4000.0), (42.0, 2000.0)]
    assert bytes_at(41.0, points) == pytest.approx(math.sqrt(1000.0 * 2000.0))
    assert bytes_at(44.0, points) == pytest.approx(4000.0)
    assert bytes_at(45.0, points) == pytest.approx(8000.0 / math.sqrt(2.0))
    assert bytes_at(39.0, points) == pytest.approx(1000.0 / math.sqrt(2.0))


@pytest.mark.gl
def test_video_rd_reports_each_variants_bytes_against_the_tiles(tmp_path, capsys):
    """A keyframe every 2 frames costs more than the shipped stream's one; every figure is finite."""
    out = tmp_path / "rd.json"
    assert main(["--sizes", "160x90", "--cameras", "1", "--frames", "4", "--variants",
                 "shipped,reopen:2,x264:ref=2", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    (camera,) = result["sizes"]["160x90"]["cameras"]
    assert camera["tiles_bytes"] > 0 and 20.0 < camera["tiles_psnr"] < 60.0
    summary = result["sizes"]["160x90"]["summary"]
    for row in summary.values():
        assert 0.0 < row["ratio_mean"] == row["ratio_worst"] < 5.0 and row["encode_ms"] > 0.0
    assert summary["reopen:2"]["ratio_mean"] > summary["shipped"]["ratio_mean"]
    for variant in summary:
        points = camera["variants"][variant]["points"]
        assert [p[0] for p in points] == [22.0, 25.0, 28.0, 31.0]
        assert points[0][1] > points[-1][1] and points[0][2] > points[-1][2], "a lower CRF: more bytes, more dB"
    assert "reopen:2" in capsys.readouterr().out


def test_video_rd_rejects_bad_variants():
    with pytest.raises(SystemExit, match="variant"):
        main(["--variants", "reopen:0"])


@pytest.mark.gl
def test_the_crf_loop_holds_the_video_near_the_tiles_psnr():
    """An orbit at 10° a frame: the loop moves the CRF from where it starts and holds the video's
    PSNR within a dB of the tiles', in fewer bytes."""
    scene = load_scene("builtin:cluster")
    references = References(scene, (160, 96))
    try:
        (camera,) = random_cameras(scene.bounds, 1, seed=0, aspect=160 / 96)
        path = orbit_around(camera, frames=36)["frames"]
        frames = np.stack([references.image(path[i % len(path)]) for i in range(48)])
    finally:
        references.release()
    figures = loop_figures(frames, 60)
    assert figures["changes"] >= 1 and CRF_RANGE[0] <= figures["crf"] <= CRF_RANGE[1]
    assert abs(figures["db_diff"]) < 1.0
    assert 0.0 < figures["ratio"] < 1.0
