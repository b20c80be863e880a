"""The coordinator's Prometheus metrics, served by ``prometheus_client`` at ``GET /metrics``.

One :class:`CoordinatorMetrics` per app, with its own registry (never the process-wide default:
tests create many apps in one process). It holds

* histograms observed as things happen: the interval between published frames, input → publish
  latency of the first frame that answers each change (the figure ``latency_ms`` averages), and
  every tile's node phases (render, readback, encode from the tile's header when it arrives, send
  from the node's ``tile_sent``);
* the figures ``/api/stats`` reports, read from the service at scrape time under the names the
  hand-written text used to have (gauges, and counters of what the scheduler and viewers count);
* the process collector (CPU seconds, resident memory, open file descriptors, start time).

The scheduler in ``tessera/`` stays free of I/O and of this library: :class:`ObservedFrameStats`
is its :class:`~tessera.scheduling.frame_stats.FrameStats` with an observer on ``record_publish``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Protocol

from prometheus_client import CollectorRegistry, Histogram, ProcessCollector
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.exposition import choose_encoder
from prometheus_client.registry import Collector

from tessera.scheduling.frame_stats import FrameStats
from tessera.wire.protocol import NODE_PHASES, TileHeader


class Describes(Protocol):
    """What the collector reads: the service's ``/api/stats`` figures."""

    def describe(self) -> dict[str, Any]: ...

#: Frame interval buckets (s): 120 fps … a frame per 10 s (pauses of render on demand land at the top).
FRAME_INTERVAL_BUCKETS = (0.008, 0.0167, 0.025, 0.033, 0.05, 0.075, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5, 10.0)
#: Input → publish buckets (s): the live pipeline answers in about 0.1 s on 2 cores.
LATENCY_BUCKETS = (0.01, 0.025, 0.05, 0.075, 0.1, 0.125, 0.15, 0.2, 0.3, 0.5, 1.0, 2.5)
#: One tile's phase buckets (s): 0.5 ms … 1 s.
PHASE_BUCKETS = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
#: The phases of ``tessera_node_phase_ms``: the node phases and their sum.
GAUGE_PHASES = (*NODE_PHASES, "busy")


class CoordinatorMetrics:
    """The metrics of one coordinator; :meth:`watch` ties the scrape-time figures to its service."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        ProcessCollector(registry=self.registry)
        self.frame_interval = Histogram(
            "tessera_frame_interval_seconds", "Time between two published frames.",
            buckets=FRAME_INTERVAL_BUCKETS, registry=self.registry)
        self.input_latency = Histogram(
            "tessera_input_to_publish_seconds",
            "Input → publish time of the first frame that shows each change (camera, scene, balancer, nodes).",
            buckets=LATENCY_BUCKETS, registry=self.registry)
        self.node_phase = Histogram(
            "tessera_node_phase_seconds", "A node's time on one tile, per phase.", ["phase"],
            buckets=PHASE_BUCKETS, registry=self.registry)
        self._phases = {phase: self.node_phase.labels(phase=phase) for phase in NODE_PHASES}
        self._last_publish: float | None = None

    def watch(self, service: Describes) -> None:
        """Report ``service``'s figures (gauges and counters) at every scrape."""
        self.registry.register(ServiceCollector(service))

    def frame_published(self, now: float, latency_s: float | None) -> None:
        """A frame was published at ``now`` (s); ``latency_s`` as in :meth:`FrameStats.record_publish`."""
        if self._last_publish is not None:
            self.frame_interval.observe(max(now - self._last_publish, 0.0))
        self._last_publish = now
        if latency_s is not None:
            self.input_latency.observe(max(latency_s, 0.0))

    def tile_arrived(self, header: TileHeader) -> None:
        """A node's tile arrived: its render, readback and encode times (ms in the header)."""
        self._phases["render"].observe(header.render_ms / 1000.0)
        self._phases["readback"].observe(header.readback_ms / 1000.0)
        self._phases["encode"].observe(header.encode_ms / 1000.0)

    def tile_sent(self, send_ms: float) -> None:
        """A node's ``tile_sent``: how long that tile took to send (ms)."""
        self._phases["send"].observe(max(send_ms, 0.0) / 1000.0)

    def exposition(self, accept: str | None) -> tuple[bytes, str]:
        """The scrape body and its content type, in the format the ``Accept`` header asks for
        (Prometheus text, or OpenMetrics), as ``prometheus_client``'s own ASGI app answers."""
        encoder, content_type = choose_encoder(accept or "")
        return encoder(self.registry), content_type


class ObservedFrameStats(FrameStats):
    """The scheduler's frame statistics, each publish also observed into ``metrics`` (same clock,
    same first-answer latency: nothing is recomputed at scrape time)."""

    def __init__(self, metrics: CoordinatorMetrics) -> None:
        super().__init__()
        self._metrics = metrics

    def record_publish(self, now: float, latency_s: float | None) -> None:
        super().record_publish(now, latency_s)
        self._metrics.frame_published(now, latency_s)


class ServiceCollector(Collector):
    """The service's current figures, as ``/api/stats`` reports them, read at scrape time."""

    def __init__(self, service: Describes) -> None:
        self.service = service

    def describe(self) -> Iterator[Metric]:
        return iter(self._families())

    def collect(self) -> Iterator[Metric]:
        stats = self.service.describe()
        families = self._families()
        gauges = {"frame_id": stats["frame"], "fps": stats["fps"], "imbalance": stats["imbalance"],
                  "imbalance_avg": stats["imbalance_avg"], "latency_ms": stats["latency_ms"],
                  "nodes": len(stats["nodes"])}
        counters = {"frames_published": stats["coordinator_cpu"]["frames"],
                    "frames_cancelled": stats["frames_cancelled"],
                    "viewer_bytes": stats["coordinator_cpu"]["viewer_bytes"]}
        for family in families:
            key = family.name.removeprefix("tessera_")
            if key.startswith("session_"):
                for session in stats["sessions"]:
                    family.add_metric([session["label"]], session[key.removeprefix("session_")])
            elif key == "node_phase_ms":
                assert isinstance(family, GaugeMetricFamily)
                for node in stats["nodes"]:
                    for phase in GAUGE_PHASES:
                        family.add_metric([str(node["id"]), phase], node[f"{phase}_ms"])
            elif isinstance(family, CounterMetricFamily):
                family.add_metric([], counters[key])
            else:
                family.add_metric([], gauges[key])
        return iter(families)

    @staticmethod
    def _families() -> list[Metric]:
        gauge, counter = GaugeMetricFamily, CounterMetricFamily
        return [
            gauge("tessera_frame_id", "Id of the newest published frame."),
            gauge("tessera_fps", "Published frames per second over the last 60 frames (0 when idle > 2 s)."),
            gauge("tessera_imbalance", "Max/mean node busy time of the last interactive frame."),
            gauge("tessera_imbalance_avg", "Mean imbalance of the last 60 interactive frames."),
            gauge("tessera_latency_ms", "Mean input → publish time (ms) of the last 60 first answers."),
            gauge("tessera_nodes", "Connected render nodes."),
            gauge("tessera_node_phase_ms", "A node's time per phase (ms) in the last complete frame, summed "
                  "over its tiles; busy is the sum of the phases.", labels=["node", "phase"]),
            gauge("tessera_session_fps", "A session's published frames per second.", labels=["session"]),
            gauge("tessera_session_latency_ms", "A session's mean input → publish time (ms).", labels=["session"]),
            gauge("tessera_session_node_share", "A session's fraction of the node time of the last 5 s.",
                  labels=["session"]),
            gauge("tessera_session_viewers", "Viewers of a session.", labels=["session"]),
            counter("tessera_frames_published", "Frames published."),
            counter("tessera_frames_cancelled", "Frames dropped before they were complete."),
            counter("tessera_viewer_bytes", "Bytes of frames sent to viewers."),
        ]
