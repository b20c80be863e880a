"""Scene state (issue 11, pure): object transforms and their validation, versions and deltas, the
coordinator's state log and a node's replica; the object hierarchy's matrices, visibility and bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.scene.graph import ObjectGraph, SceneObject, transform_boxes
from tessera.scene.state import (
    ObjectPatch,
    ObjectState,
    SceneState,
    SceneStateError,
    StateDelta,
    StateLog,
    StateReplica,
    UnknownObjectError,
    state_from_json,
)

NAN, INF = float("nan"), float("inf")
S45 = math.sqrt(0.5)
#: 90° about +z.
QUARTER_Z = (0.0, 0.0, S45, S45)


def scene(names: str = "abc") -> SceneState:
    return SceneState(0, 0.0, {name: ObjectState() for name in names})


# ------------------------------------------------------------------------------------- ObjectState


def test_matrix_is_translation_rotation_scale() -> None:
    # (1, 0, 0) scaled by 2 in x → (2, 0, 0), turned 90° about z → (0, 2, 0), moved → (1, 4, 3).
    state = ObjectState((1.0, 2.0, 3.0), QUARTER_Z, (2.0, 1.0, 1.0))
    point = state.matrix() @ np.array([1.0, 0.0, 0.0, 1.0])
    np.testing.assert_allclose(point, [1.0, 4.0, 3.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(ObjectState().matrix(), np.identity(4))


def test_rotation_is_normalised() -> None:
    state = ObjectState(rotation=(0.0, 0.0, 2.0, 2.0))
    assert state.rotation == pytest.approx(QUARTER_Z)
    assert ObjectState(rotation=state.rotation) == state            # a unit rotation is kept bit for bit
    assert ObjectState.from_json(state.to_json()) == state


@pytest.mark.parametrize(("data", "message"), [
    ({"translation": [NAN, 0, 0]}, "wheel.translation is not finite"),
    ({"translation": [1, 2]}, "wheel.translation must be a list of 3 numbers"),
    ({"translation": [1, True, 2]}, "wheel.translation must be numbers"),
    ({"rotation": [0, 0, 0, 0]}, "wheel.rotation must be a quaternion of non-zero length"),
    ({"rotation": [0, 0, INF, 1]}, "wheel.rotation is not finite"),
    ({"rotation": [1e200, 1e200, 0, 0]}, "non-zero length"),
    ({"scale": [1, 0, 1]}, "wheel.scale must be non-zero"),
    ({"scale": [1, INF, 1]}, "wheel.scale is not finite"),
    ({"visible": 1}, "wheel.visible must be true or false"),
    ({"colour": [1, 0, 0]}, "wheel: unknown fields ['colour']"),
    ([1, 2, 3], "wheel: must be a JSON object"),
])
def test_bad_values_are_refused_with_the_field_named(data: object, message: str) -> None:
    with pytest.raises(SceneStateError, match=message.replace("[", r"\[").replace("]", r"\]")):
        ObjectPatch.from_json(data, "wheel")


def test_patch_sets_only_its_fields() -> None:
    base = ObjectState((1.0, 2.0, 3.0), QUARTER_Z, (2.0, 2.0, 2.0), True)
    patched = base.patched(ObjectPatch.from_json({"visible": False, "scale": [3, 3, 3]}))
    assert patched == ObjectState((1.0, 2.0, 3.0), QUARTER_Z, (3.0, 3.0, 3.0), False)
    assert base.patched(ObjectPatch()) is base
    assert ObjectPatch.from_json({"rotation": [0, 0, 1, 1]}).to_json() == {"rotation": pytest.approx(QUARTER_Z)}


def test_mirrored_matrix_decomposes_with_a_negative_scale() -> None:
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    mirror[:3, 3] = [0.5, 0.0, -1.0]
    state = ObjectState.from_matrix(mirror)
    np.testing.assert_allclose(state.matrix(), mirror, atol=1e-12)
    assert state.scale[0] < 0


unit = st.floats(-1.0, 1.0)


@settings(max_examples=60, deadline=None)
@given(st.tuples(*[st.floats(-50, 50)] * 3), st.tuples(unit, unit, unit, unit).filter(lambda q: math.hypot(*q) > 0.1),
       st.tuples(*[st.floats(0.05, 20)] * 3))
def test_from_matrix_inverts_matrix(translation: tuple, rotation: tuple, scale: tuple) -> None:
    state = ObjectState(translation, rotation, scale)
    again = ObjectState.from_matrix(state.matrix())
    np.testing.assert_allclose(again.matrix(), state.matrix(), atol=1e-9 * max(1.0, max(scale)))


# ---------------------------------------------------------------------------------- versions, deltas


def test_update_makes_the_next_version_with_the_changed_objects() -> None:
    first = scene()
    moved = ObjectState(translation=(1.0, 0.0, 0.0))
    second = first.updated({"a": moved, "b": ObjectState()}, time=0.5)
    assert (second.version, second.time) == (1, 0.5)
    assert second.objects["a"] == moved and first.objects["a"] == ObjectState()
    delta = second.delta_from(first)
    assert (delta.base, delta.version, delta.time, dict(delta.objects)) == (0, 1, 0.5, {"a": moved})
    assert first.apply(delta).same_as(second)
    assert second.updated({"a": moved}) is second                  # nothing changed: no new version


def test_delta_goes_either_way() -> None:
    first = scene()
    second = first.updated({"c": ObjectState(visible=False)})
    back = first.delta_from(second)
    assert (back.base, back.version, list(back.objects)) == (1, 0, ["c"])
    assert second.apply(back).same_as(first)


def test_delta_needs_its_base_and_known_objects() -> None:
    first = scene()
    second = first.updated({"a": ObjectState(visible=False)})
    third = second.updated({"b": ObjectState(visible=False)})
    with pytest.raises(SceneStateError, match="does not apply to state version 0; a full state is needed"):
        first.apply(third.delta_from(second))
    with pytest.raises(UnknownObjectError, match=r"unknown objects: \['zz'\]"):
        first.apply(StateDelta(0, 1, 0.0, {"zz": ObjectState()}))
    with pytest.raises(UnknownObjectError):
        first.updated({"zz": ObjectState()})
    with pytest.raises(UnknownObjectError):
        first.patched({"zz": ObjectPatch(visible=False)})


def test_json_round_trip_and_validation() -> None:
    first = scene()
    second = first.patched({"b": ObjectPatch(rotation=QUARTER_Z, scale=(2.0, 2.0, 2.0))}, time=1.5)
    full = state_from_json(second.to_json())
    assert isinstance(full, SceneState) and full.version == 1 and full.same_as(second)
    delta = state_from_json(second.delta_from(first).to_json())
    assert isinstance(delta, StateDelta) and first.apply(delta).same_as(second)
    for bad, message in [
        ({"version": 1, "time": NAN, "objects": {}}, "time is not finite"),
        ({"version": -1, "time": 0.0, "objects": {}}, "version must be an integer >= 0"),
        ({"version": 1, "time": 0.0}, "lacks 'objects'"),
        ({"version": 1, "time": 0.0, "objects": {"a": {"scale": [0, 1, 1]}}}, "a.scale must be non-zero"),
        ({"version": 1, "time": 0.0, "objects": {}, "extra": 1}, "unknown scene state fields"),
    ]:
        with pytest.raises(SceneStateError, match=message):
            state_from_json(bad)


def test_log_gives_deltas_from_what_a_node_has_and_full_states_to_newcomers() -> None:
    log = StateLog(scene(), history=3)
    for step in range(1, 5):
        log.update({"a": ObjectState(translation=(float(step), 0.0, 0.0))}, time=step * 0.1)
    assert log.current.version == 4
    assert isinstance(log.payload_for(None), SceneState)            # a node that joins now
    assert isinstance(log.payload_for(0), SceneState)               # version 0 is no longer kept
    delta = log.payload_for(3)
    assert isinstance(delta, StateDelta) and (delta.base, delta.version) == (3, 4)
    back = log.payload_for(4, version=2)                             # an older frame still in flight
    assert isinstance(back, StateDelta) and back.objects["a"].translation == (2.0, 0.0, 0.0)
    with pytest.raises(SceneStateError, match="no longer kept"):
        log.payload_for(4, version=1)
    assert log.update({"a": log.current.objects["a"]}) is log.current


def test_replica_catches_up_from_a_full_state_then_follows_deltas() -> None:
    log = StateLog(scene())
    log.update({"a": ObjectState(visible=False)}, time=0.2)
    replica = StateReplica()
    with pytest.raises(SceneStateError, match="before any full state"):
        replica.receive(StateDelta(1, 2, 0.0))
    sent = log.current.version
    assert replica.receive(state_from_json(log.payload_for(None).to_json())).same_as(log.current)
    for step in range(3):
        log.patch({"b": ObjectPatch(translation=(0.0, float(step), 0.0))}, time=0.3 + step)
        payload = log.payload_for(sent)
        sent = log.current.version
        got = replica.receive(state_from_json(payload.to_json()))
        assert got.version == sent and got.same_as(log.current)


# ------------------------------------------------------------------------------------ object graph


def truck() -> ObjectGraph:
    """body at x = 10; its axle 1 unit up (no geometry); the wheel on the axle, a unit box."""
    body_box, wheel_box = np.array([[8.0, 0.0, -1.0], [12.0, 2.0, 1.0]]), np.array([[9.5, 0.5, -0.5], [10.5, 1.5, 0.5]])
    return ObjectGraph([
        SceneObject("body", -1, ObjectState(translation=(10.0, 0.0, 0.0)), body_box, 12),
        SceneObject("axle", 0, ObjectState(translation=(0.0, 1.0, 0.0)), None, 0),
        SceneObject("wheel", 1, ObjectState(), wheel_box, 6),
    ])


def test_world_matrices_follow_the_hierarchy() -> None:
    graph = truck()
    state = graph.base.patched({"axle": ObjectPatch(rotation=QUARTER_Z)})
    world = graph.world_matrices(state)
    np.testing.assert_allclose(world[2] @ [1.0, 0.0, 0.0, 1.0], [10.0, 2.0, 0.0, 1.0], atol=1e-12)
    model = graph.model_matrices(state)
    assert (model[0] == np.identity(4)).all()                       # the body did not move: exactly
    # The wheel's base-pose point (11, 1, 0) turns about the axle at (10, 1, 0) to (10, 2, 0).
    np.testing.assert_allclose(model[2] @ [11.0, 1.0, 0.0, 1.0], [10.0, 2.0, 0.0, 1.0], atol=1e-12)
    assert graph.moved(state).tolist() == [False, True, True]
    assert (graph.model_matrices(graph.base) == np.identity(4)).all()


def test_visibility_is_inherited_and_bounds_follow_the_state() -> None:
    graph = truck()
    hidden = graph.base.patched({"axle": ObjectPatch(visible=False)})
    assert graph.visibility(hidden).tolist() == [True, False, False]
    np.testing.assert_allclose(graph.bounds(graph.base), [[8.0, 0.0, -1.0], [12.0, 2.0, 1.0]])
    lifted = graph.base.patched({"axle": ObjectPatch(translation=(0.0, 5.0, 0.0))})
    np.testing.assert_allclose(graph.bounds(lifted), [[8.0, 0.0, -1.0], [12.0, 5.5, 1.0]])
    assert graph.bounds(graph.base.patched({"body": ObjectPatch(visible=False)})) is None


def test_posed_layers_animation_then_overrides() -> None:
    graph = truck()
    state = graph.posed(2.0, animated={"wheel": ObjectPatch(rotation=QUARTER_Z, translation=(1.0, 0.0, 0.0))},
                        overrides={"wheel": ObjectPatch(translation=(0.0, 0.0, 3.0))})
    assert state.time == 2.0
    assert state.objects["wheel"] == ObjectState((0.0, 0.0, 3.0), QUARTER_Z)
    assert state.objects["body"] == graph.objects[0].base
    with pytest.raises(UnknownObjectError, match="unknown object 'tyre'"):
        graph.posed(0.0, overrides={"tyre": ObjectPatch()})
    listed = graph.to_json(state)
    assert listed[2]["parent"] == "axle" and listed[2]["translation"] == [0.0, 0.0, 3.0]
    assert listed[1]["bounds"] is None and listed[0]["triangles"] == 12


def test_graph_refuses_duplicate_names_and_forward_parents() -> None:
    box = SceneObject("a", -1, ObjectState(), None, 0)
    with pytest.raises(SceneStateError, match="used twice"):
        ObjectGraph([box, box])
    with pytest.raises(SceneStateError, match="does not come before it"):
        ObjectGraph([SceneObject("a", 1, ObjectState(), None, 0), SceneObject("b", -1, ObjectState(), None, 0)])


def test_transform_boxes_hand_computed() -> None:
    boxes = np.array([[[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]]])
    turn = ObjectState((1.0, 0.0, 0.0), QUARTER_Z).matrix()          # (x, y) → (−y + 1, x)
    np.testing.assert_allclose(transform_boxes(boxes, turn), [[[0.0, 0.0, 0.0], [1.0, 2.0, 1.0]]], atol=1e-12)
