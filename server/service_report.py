"""``/api/stats`` of the coordinator: :class:`ServiceReport`, the part of
:class:`server.service.RenderService` that describes a session's frames, the nodes, the coordinator's
CPU and every session's summary, and how the nodes hold a scene."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from server.sessions import Session
from server.still_refinement import still_figures
from tessera.scheduling.fair_share import SHARE_WINDOW_S

if TYPE_CHECKING:
    from server.nodes import NodeLink
    from server.render_jobs import RenderJobs
    from server.settings import Settings
    from tessera.scheduling.job_scheduler import JobScheduler


class ServiceReport:
    """The coordinator's figures; mixed into :class:`server.service.RenderService`, which owns the
    attributes named below."""

    settings: Settings
    scheduler: JobScheduler
    jobs: RenderJobs
    default: Session
    sessions: dict[str, Session]
    nodes: dict[int, NodeLink]
    cpu_ms: dict[str, float]

    def scene_on_nodes(self, scene: str) -> dict[str, Any]:
        """How the nodes hold scene ``scene`` (:meth:`server.sessions.SessionHost.scene_on_nodes`)."""
        loading = [link.loading[scene] for link in self.nodes.values() if scene in link.loading]
        holding = sum(scene in link.scene_mb and scene not in link.loading for link in self.nodes.values())
        least = min(loading, default=None)
        return {"loading": None if least is None else {
                    "fraction": round(least[0], 3), "message": least[1], "nodes_ready": holding,
                    "nodes": holding + len(loading)},
                "scene_mb": {link.name: link.scene_mb[scene] for link in self.nodes.values() if scene in link.scene_mb}}

    def describe(self, session: Session | None = None, public: bool = False) -> dict[str, Any]:
        """``/api/stats``: ``session``'s figures (default: the default session's) with the nodes', the
        coordinator's and every session's summary; ``public``: sessions named by their labels, not
        by the ids that drive them (for a watcher)."""
        session = session or self.default
        scheduler, frames = self.scheduler, session.frames
        stats, latest, now = frames.stats, session.store.latest, time.monotonic()
        return {
            "frame": max(session.store.last_id, 0),
            "fps": round(stats.fps(now), 2),
            "size": list(session.size),
            "balancer": session.balancer.name,
            **frames.mode.describe(),
            "balancer_params": session.balancer.params,
            "imbalance": round(stats.imbalance, 4),
            "imbalance_avg": round(stats.imbalance_avg, 4),
            "latency_ms": round(stats.latency_ms, 2),
            "frames_in_flight": len(frames.frames),
            "frames_cancelled": frames.frames_cancelled,
            "still": bool(latest and latest.still),
            "still_samples": still_figures(latest, frames.demand.still_plan),
            "settled": session.settled,
            "lod_error_px": frames.lod_bound,
            "point_budget": frames.point_budget,
            "loading": self.scene_on_nodes(session.scene)["loading"],
            "scene": session.name,
            "scene_state": session.scene_state(),
            "session": session.label if public else session.id,
            "codec": self.settings.codec.name.lower(),
            "interactive_quality": self.settings.interactive_quality,
            "still_codec": self.settings.still_codec.name.lower() if self.settings.still_codec is not None else "none",
            "viewers": len(session.viewers.slots),
            "viewer_stats": session.viewers.describe(),
            "stream": self.settings.stream,
            "video": session.viewers.describe_video(),
            "frame_lock": session.viewers.lock.describe() if session.wall is not None else None,
            "coordinator_cpu": {
                "frames": stats.frames_published,
                "receive_ms": round(self.cpu_ms["receive"], 3),
                "publish_ms": round(self.cpu_ms["publish"], 3),
                "merge_ms": round(self.cpu_ms["merge"], 3),
                "still_ms": round(sum(s.refiner.cpu_ms for s in self.sessions.values()), 3),
                "process_ms": round(time.process_time() * 1000.0, 3),
                "viewer_bytes": sum(s.viewers.bytes_published for s in self.sessions.values()),
            },
            "jobs": self.jobs.describe_session(session.id),
            "sessions": [s.summary(now, public) for s in self.sessions.values()],
            "share_window_s": SHARE_WINDOW_S,
            "nodes": [link.describe(scheduler.nodes[link.node_id])   # not one the scheduler let go (closing)
                      for link in sorted(self.nodes.values(), key=lambda n: n.node_id)
                      if link.node_id in scheduler.nodes],
        }
