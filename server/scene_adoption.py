"""A session takes its scene as the first node that loaded it reported it (``scene_ready``): its
objects and animations, primitive groups and bounds, and a camera that frames it if it has none."""

from __future__ import annotations

import numpy as np

from server.sessions import Session
from tessera.geometry import default_camera
from tessera.scene.animation import Animation, AnimationError
from tessera.scene.graph import ObjectGraph
from tessera.scene.state import SceneStateError
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.scheduler import FrameScheduler
from tessera.wire.messages import SceneReady, ViewerScene
from tessera.wire.protocol import ProtocolError


def timeline_of(message: SceneReady, now: float) -> SceneTimeline:
    """The scene's objects and animations as a node reported them; ProtocolError when they do not
    make a scene."""
    assert message.objects is not None
    try:
        graph = ObjectGraph.from_json([item.model_dump() for item in message.objects])
        animations = [Animation.from_keyframes_json(item.model_dump()) for item in message.animations]
        return SceneTimeline(graph, animations, now)
    except (SceneStateError, AnimationError) as exc:
        raise ProtocolError(f"scene_ready: {exc}") from None


def adopt_scene(scheduler: FrameScheduler, session: Session, message: SceneReady, now: float) -> None:
    """``session`` takes the scene ``message`` reports: its objects, groups and bounds, and a
    camera that frames it if the session has none; its viewers are told."""
    bounds = np.asarray(message.bounds, dtype=np.float64)
    if message.objects is not None:
        scheduler.set_scene(timeline_of(message, now), now, session.id)
    session.bounds, session.state, session.error = bounds, "ready", None
    if message.points is not None:      # a point cloud (issue 36): budget, EDL after a sort-last merge
        scheduler.sessions[session.id].set_points(bounds)
    if message.groups is not None:
        scheduler.set_groups(np.asarray(message.groups.boxes, dtype=np.float64),
                             np.asarray(message.groups.counts, dtype=np.float64), bounds,
                             message.groups.objects, session.id)
    if session.camera is None:
        width, height = session.size
        scheduler.set_camera(default_camera(bounds, aspect=width / height), now, session_id=session.id)
    assert session.camera is not None
    if session.pending_state is not None:
        session.restore_state(session.pending_state, now)
        session.pending_state = None
    session.viewers.broadcast(ViewerScene(bounds=message.bounds, camera=session.camera))
