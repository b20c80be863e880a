"""bench.bigscene's report (issue 32): the moving frame's PSNR against full detail and against full
detail's JPEG, and the worst of the cameras it was compared from."""

from __future__ import annotations

from bench import bigscene


def test_report_names_the_worst_camera():
    cameras = [{"camera": "orbit 0°", "psnr_vs_full": 40.1, "psnr_vs_full_jpeg": 41.0},
               {"camera": "half 20°", "psnr_vs_full": 36.2, "psnr_vs_full_jpeg": 37.9}]
    moving = {"fps": 9.0, "latency_p50_ms": 180.0, "latency_p50_frames": 1.6, "triangles_per_frame": 8e5,
              "busy_ms": 90.0, "bound_px": 1.0, "psnr_vs_full": 40.1, "psnr_vs_full_jpeg": 41.0,
              "worst_vs_full": cameras[1], "worst_vs_full_jpeg": cameras[1], "cameras": cameras}
    text = bigscene.report({"scene": "model.ply", "nodes": 3, "size": [640, 360],
                            "modes": {"sort-first": {"moving_lod_on": moving}}})
    assert "PSNR 40.1 dB (41.0 dB against full detail's JPEG)" in text
    assert "worst of 2 cameras: 36.2 dB (half 20°), 37.9 dB against full detail's JPEG (half 20°)" in text
    one = {**moving, "cameras": cameras[:1]}
    assert "worst of" not in bigscene.report({"scene": "m", "nodes": 3, "size": [640, 360],
                                              "modes": {"sort-first": {"moving_lod_on": one}}})
