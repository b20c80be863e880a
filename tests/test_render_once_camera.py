"""``--render-once --camera FILE`` reads a camera, or the coordinator's ``GET /api/camera`` answer as
a user saves it (``curl …/api/camera > cam.json``); anything else is refused with the file named."""

from __future__ import annotations

import json

import pytest

from node.render_once import read_camera
from tessera.geometry import CameraError

CAMERA = {"eye": [1.0, 2.0, 3.0], "target": [0.0, 0.5, 0.0], "up": [0.0, 1.0, 0.0], "fovy_deg": 40.0}


def test_a_camera_and_the_api_answer_holding_it_read_alike(tmp_path):
    bare, answer = tmp_path / "camera.json", tmp_path / "answer.json"
    bare.write_text(json.dumps(CAMERA))
    answer.write_text(json.dumps({"camera": CAMERA, "frame": 8, "bounds": [[-1, -1, -1], [1, 1, 1]]}))
    assert read_camera(answer) == read_camera(bare)
    assert read_camera(bare).fovy_deg == 40.0


@pytest.mark.parametrize("content", [{"camera": CAMERA, "eye": [0, 0, 1]}, {"camera": "front"}, {"frame": 8}])
def test_anything_else_is_refused_with_the_file_named(tmp_path, content):
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(content))
    with pytest.raises(CameraError, match=r"camera file .*camera\.json"):
        read_camera(path)
