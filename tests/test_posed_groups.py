"""Load groups that follow their objects (issue 11 item 5): a group is moved with its object's model
matrix and dropped while it is hidden before it is projected, so the balancers that read groups
see the load where it is in the frame's state. Pure; the scheduler on a virtual clock."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from tessera.balancers.base import BalanceInput, Partition, ProjectedGroups
from tessera.balancers.projection import posed_groups, project_groups
from tessera.balancers.static import StaticBalancer
from tessera.scene.graph import ObjectGraph, SceneObject
from tessera.scene.state import ObjectPatch
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tests.test_scheduler import camera
from tests.test_scheduler_scene import finish

SIZE = (64, 32)
#: car: two groups at x −2…−1 (its own bounds), tree: one group at x 1…2
BOXES = np.array([[-2, 0, 0, -1.5, 1, 1], [-1.5, 0, 0, -1, 1, 1], [1, 0, 0, 2, 1, 1]], dtype=np.float64)
COUNTS = np.array([100, 200, 50])
OWNERS = np.array([0, 0, 1])


def graph() -> ObjectGraph:
    return ObjectGraph([SceneObject("car", bounds=np.array([[-2.0, 0, 0], [-1, 1, 1]]), triangles=300),
                        SceneObject("tree", bounds=np.array([[1.0, 0, 0], [2, 1, 1]]), triangles=50)])


def test_groups_move_with_their_object_and_hidden_ones_are_dropped():
    objects = graph()
    state = objects.posed(0.0, overrides={"car": ObjectPatch(translation=(3.0, 0.5, 0.0)),
                                          "tree": ObjectPatch(visible=False)})
    boxes, counts = posed_groups(BOXES, COUNTS, OWNERS, objects, state)
    assert np.array_equal(boxes, BOXES[:2] + np.array([3.0, 0.5, 0.0, 3.0, 0.5, 0.0]))
    assert counts.tolist() == [100.0, 200.0] and counts.dtype == np.float64
    # Turned a quarter about z: a box around the turned box.
    turned = objects.posed(0.0, overrides={"car": ObjectPatch(rotation=(0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)))})
    boxes, counts = posed_groups(BOXES, COUNTS, OWNERS, objects, turned)
    assert np.allclose(boxes[0], [-1, -2, 0, 0, -1.5, 1]) and np.array_equal(boxes[2], BOXES[2])
    # At the base pose nothing changes.
    boxes, counts = posed_groups(BOXES, COUNTS, OWNERS, objects, objects.base)
    assert np.array_equal(boxes, BOXES) and counts.tolist() == [100.0, 200.0, 50.0]


class Recording(StaticBalancer):
    """The equal split, remembering the groups each partition was asked with."""

    uses_groups: ClassVar[bool] = True

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[ProjectedGroups | None] = []

    def partition(self, inputs: BalanceInput) -> Partition:
        self.seen.append(inputs.groups)
        return super().partition(inputs)


def test_the_balancer_gets_the_groups_of_the_frames_state():
    balancer = Recording()
    s = FrameScheduler(SchedulerConfig(size=SIZE, max_fps=1e6, settle_frames=0, max_in_flight=4), balancer)
    for node_id in (1, 2):
        s.add_node(node_id, 0.0)
        s.node_ready(node_id, 0.0)
    objects = graph()
    scene_bounds = np.array([[-2.0, 0, 0], [2, 1, 1]])
    s.set_scene(SceneTimeline(objects), 0.0)
    s.set_groups(BOXES, COUNTS, scene_bounds, OWNERS)
    s.set_camera(camera(), 0.0)
    s.drain()
    before = balancer.seen[-1]
    assert before is not None
    expected = project_groups(BOXES, COUNTS, camera(), SIZE, scene_bounds)
    assert np.array_equal(before.boxes, expected.boxes) and np.array_equal(before.weights, expected.weights)
    finish(s, 1, 0.05)
    s.set_objects({"car": ObjectPatch(translation=(2.5, 0.0, 0.0)), "tree": ObjectPatch(visible=False)}, 0.1)
    s.drain()
    after = balancer.seen[-1]
    assert after is not None and len(balancer.seen) == 2
    state = s.in_flight[2].state
    assert state is not None
    moved = project_groups(*posed_groups(BOXES, COUNTS, OWNERS, objects, state), camera(), SIZE,
                           objects.bounds(state))
    assert np.array_equal(after.boxes, moved.boxes) and after.weights.tolist() == [100.0, 200.0]
    assert after.boxes[:, 0].min() > before.boxes[:, 0].min()      # the car's load moved right
    # Groups without owners stay at the base pose.
    s.set_groups(BOXES, COUNTS, scene_bounds)
    assert s.default.groups_for is not None
    still = s.default.groups_for(camera(), state)
    assert still is not None and np.array_equal(still.boxes, expected.boxes)
