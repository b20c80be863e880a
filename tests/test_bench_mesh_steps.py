"""bench.mesh_steps (issue 33): the height field it pushes, and a short run end to end against a real
coordinator (every step pushed reaches a published frame when the machine keeps up, each timed to its
first frame)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench import mesh_steps


def test_the_height_field_has_the_triangles_asked_for_and_a_moving_wave():
    grid, faces = mesh_steps.height_field(100_000)
    assert abs(len(faces) - 100_000) < 1000 and faces.max() == len(grid) - 1 and faces.min() == 0
    assert not np.allclose(mesh_steps.wave(grid, 0.0), mesh_steps.wave(grid, 0.1))


@pytest.mark.integration
@pytest.mark.gl
def test_a_short_run_pushes_each_step_to_the_screen(tmp_path):
    out = tmp_path / "steps.json"
    mesh_steps.main(["--nodes", "1", "--triangles", "2000", "--rate", "2", "--steps", "3", "--size", "96x64",
                     "--turn-s", "1.5", "--json", str(out)])
    result = json.loads(out.read_text())
    assert result["steps_shown"] == 3 and result["reader_error"] is None
    assert 0 < result["steps_per_s_from_start"] <= 2.0 and result["triangles"] == 2048
    assert result["steps_per_s"] > 0, "the rate between the first step on screen and the last"
    assert 0 < result["latency_s"]["p50"] <= result["latency_s"]["p90"]
    assert result["frames_per_s_turning"] > 0 and result["of_frame_rate"] > 0
