"""What the frame scheduler asks its adapter to do (:meth:`tessera.scheduling.scheduler.FrameScheduler.drain`):
send a render message, cancel frames on a node, load the scene, publish a frame, close a node,
report a failed balancer."""

from __future__ import annotations

from dataclasses import dataclass

from tessera.scheduling.frame_jobs import FrameJob
from tessera.wire.messages import Render, ShareSpec


@dataclass(frozen=True, slots=True)
class RenderTiles:
    """Send ``message`` to node ``node_id``."""

    node_id: int
    message: Render


@dataclass(frozen=True, slots=True)
class CancelFrames:
    """Tell node ``node_id`` to drop its queued tiles of ``frames`` (superseded)."""

    node_id: int
    frames: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class PublishFrame:
    """``job`` is complete: show it (frames come in increasing id order)."""

    job: FrameJob


@dataclass(frozen=True, slots=True)
class CloseNode:
    """Disconnect node ``node_id`` (it has already been removed from the schedule)."""

    node_id: int
    code: int
    reason: str


@dataclass(frozen=True, slots=True)
class LoadScene:
    """Tell node ``node_id`` to load scene ``scene`` (None: the coordinator's own), or only
    ``share`` of it (sort-last; it drops the share of that scene it held)."""

    node_id: int
    share: ShareSpec | None = None
    scene: str | None = None


@dataclass(frozen=True, slots=True)
class BalancerFailed:
    """The balancer raised or gave a partition that is not one: the static split was used."""

    reason: str


Action = RenderTiles | CancelFrames | PublishFrame | CloseNode | LoadScene | BalancerFailed
