"""Clip planes and section boxes without GL (issue 35): the JSON users send, the half-spaces the
nodes cut by, and which chunk boxes culling may drop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tessera.tools.clipping import DEFAULT_CAP_COLOR, MAX_PLANES, ClipError, ClipState, clipped_boxes
from tessera.wire.messages import Render


def test_json_round_trip_and_defaults() -> None:
    state = ClipState.from_json({"planes": [{"point": [1, 2, 3], "normal": [0, 0, 2]}],
                                 "box": {"min": [-1, -1, -1], "max": [1, 2, 3]}})
    assert state.planes[0].normal == (0.0, 0.0, 1.0)
    assert state.cap == DEFAULT_CAP_COLOR
    assert ClipState.from_json(state.to_json()) == state
    assert ClipState.from_json({"cap": False}).cap is None
    assert not ClipState.from_json({}).active
    assert ClipState.from_json({"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}).active


def test_halfspaces_keep_what_every_one_keeps() -> None:
    state = ClipState.from_json({"planes": [{"point": [0, 0.5, 0], "normal": [0, -1, 0]}],
                                 "box": {"min": [-1, -1, -1], "max": [1, 1, 1]}})
    halfspaces = state.halfspaces()
    assert halfspaces.shape == (7, 4)

    def kept(point: list[float]) -> bool:
        return bool((halfspaces[:, :3] @ np.asarray(point) + halfspaces[:, 3] >= 0).all())

    assert kept([0, 0, 0]) and kept([0.9, 0.5, -0.9])
    assert not kept([0, 0.6, 0])      # above the plane
    assert not kept([1.1, 0, 0]) and not kept([0, -1.01, 0]) and not kept([0, 0, 1.2])   # outside the box


@pytest.mark.parametrize("data, words", [
    ({"planes": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]}, "non-zero length"),
    ({"planes": [{"point": [0, math.nan, 0], "normal": [0, 1, 0]}]}, "planes[0].point"),
    ({"planes": [{"point": [0, 0, 0], "normal": [0, 1, 0]}] * (MAX_PLANES + 1)}, f"at most {MAX_PLANES}"),
    ({"planes": [[0, 1, 0, 0]]}, "planes[0] must be an object"),
    ({"box": {"min": [0, 0, 0], "max": [1, 0, 1]}}, "below box max"),
    ({"box": {"min": [0, 0, 0]}}, "box must be an object"),
    ({"box": {"min": [0, 0, 0], "max": [1, 1, math.inf]}}, "box.max"),
    ({"cap": "yes"}, "cap must be true or false"),
    ({"cap_color": [1, 2, 0]}, "cap_color"),
    ({"plane": []}, "unknown clip fields"),
    ([], "JSON object"),
])
def test_bad_clip_states_are_refused_with_the_field(data, words: str) -> None:
    with pytest.raises(ClipError, match=words.replace("[", r"\[").replace("]", r"\]")):
        ClipState.from_json(data)


def test_boxes_wholly_cut_away() -> None:
    halfspaces = ClipState.from_json({"box": {"min": [0, 0, 0], "max": [1, 1, 1]}}).halfspaces()
    boxes = np.array([[[0.2, 0.2, 0.2], [0.4, 0.4, 0.4]],      # inside
                      [[-1, -1, -1], [2, 2, 2]],               # around the box
                      [[0.9, 0.9, 0.9], [1.5, 1.5, 1.5]],      # straddling a corner
                      [[1.01, 0, 0], [2, 1, 1]],               # beyond +x
                      [[0, -3, 0], [1, -0.01, 1]]])            # below -y
    assert clipped_boxes(boxes, halfspaces).tolist() == [False, False, False, True, True]
    assert not clipped_boxes(boxes, np.zeros((0, 4))).any()


def test_render_message_carries_clip_and_highlight() -> None:
    clip = {"planes": [{"point": [0, 0, 0], "normal": [1, 0, 0]}], "box": None, "cap": True,
            "cap_color": [0.5, 0.5, 0.5]}
    data = {"type": "render", "frame": 3, "camera": {"eye": [0, 0, 5], "target": [0, 0, 0]}, "size": [64, 48],
            "codec": "png", "tiles": [{"tile": 0, "rect": [0, 0, 64, 48]}], "clip": clip, "highlight": "wheel"}
    render = Render.from_json(data)
    assert render.clip == ClipState.from_json(clip) and render.highlight == "wheel"
    assert Render.from_json(render.to_json()) == render
    plain = Render.from_json({**data, "clip": None, "highlight": None}).to_json()
    assert "clip" not in plain and "highlight" not in plain
    with pytest.raises(ValueError, match=r"render\.clip"):
        Render.from_json({**data, "clip": {"planes": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]}})
