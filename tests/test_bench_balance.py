"""The balancing benchmark: the virtual cluster driving the coordinator's own scheduler (pure, tile
costs from a model instead of renders), its summary, the T1/speedup figures, and one short real
run of ``python -m bench.balance`` on llvmpipe."""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
import pytest

from bench.balance import (
    build_parser,
    check_args,
    frame_groups,
    frame_states,
    ideal_speedup,
    pace_fps,
    single_node_ms,
    speedup_figures,
)
from bench.paths import make_path
from bench.virtual_cluster import (
    FrameRecord,
    Phases,
    VirtualCluster,
    VirtualNode,
    rect_sums,
    run_path,
    summarize,
    summed_area,
)
from tessera.balancers import create_balancer
from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups, Tile
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Rect, default_camera
from tessera.scheduling.scheduler import SchedulerConfig
from tessera.wire.codec import Codec
from tests.balance_support import cameras

SIZE = (100, 10)


def map_measure(cost: np.ndarray):
    """``measure(camera, rects)`` from an (H, W) cost map (ms per pixel), the same for every camera;
    a tenth of each tile's cost is read-back, a tenth encode."""
    table = summed_area(cost)

    def measure(camera: int, rects: Sequence[Rect]) -> list[Phases]:
        return [Phases(0.8 * c, 0.1 * c, 0.1 * c) for c in rect_sums(table, rects)]

    return measure


def fixed_measure(phases: Sequence[Phases]):
    """``measure(camera, rects)``: the i-th rect of a frame costs ``phases[i]``, every camera."""

    def measure(camera: int, rects: Sequence[Rect]) -> list[Phases]:
        assert len(rects) == len(phases)
        return list(phases)

    return measure


class Fixed(Balancer):
    """The same partition every frame; records every input it is given."""

    name = "fixed"
    uses_groups = True
    defaults: ClassVar[Mapping[str, float | int | bool]] = {}

    def __init__(self, partition: Partition) -> None:
        super().__init__()
        self.fixed = partition
        self.inputs: list[BalanceInput] = []

    def partition(self, inputs: BalanceInput) -> Partition:
        self.inputs.append(inputs)
        return self.fixed


def halves(pull: bool = False) -> Partition:
    return Partition((Tile(Rect(0, 0, 50, 10), None if pull else 1), Tile(Rect(50, 0, 50, 10), None if pull else 2)),
                     pull=pull)


def run(balancer: Balancer, measure, frames: int, slowdowns: Mapping[int, float] | None = None,
        in_flight: int = 1, max_fps: float = math.inf, **kw) -> list[FrameRecord]:
    """``frames`` cameras on nodes 1 and 2 (slowdowns default 1); every frame is published."""
    records, _ = run_path(balancer, measure, cameras(frames), SIZE, slowdowns or {1: 1.0, 2: 1.0}, in_flight=in_flight,
                          max_fps=max_fps, **kw)
    assert [r.camera for r in records] == list(range(frames))
    return records


# ------------------------------------------------------------------------------- node times


def test_slowdowns_scale_node_times_and_the_timings_fed_back() -> None:
    """Halves of 10 and 5 ms (speed 1), node 2 three times as slow: 10 and 15 ms; the next frame
    (paced, so it starts after this one is done) is partitioned seeing each phase × the slowdown of
    the node that rendered it."""
    fixed = Fixed(halves())
    records = run(fixed, fixed_measure([Phases(8.0, 1.0, 1.0), Phases(4.0, 0.5, 0.5)]), 2, {1: 1.0, 2: 3.0},
                  max_fps=30.0)
    assert records[0].node_ms == {1: 10.0, 2: 15.0} and records[0].frame_ms == 15.0
    assert records[0].work_ms == 15.0 and records[0].spans == ((0.0, 10.0, 10.0), (0.0, 15.0, 5.0))
    assert [(t.node_id, t.render_ms, t.readback_ms, t.encode_ms) for t in fixed.inputs[1].timings] == [
        (1, 8.0, 1.0, 1.0), (2, 12.0, 1.5, 1.5)]


def test_ideal_and_efficiency() -> None:
    """Uniform cost (20 ms of work), equal halves: balanced at equal speeds; node 2 twice as slow:
    times 10 and 20 ms, ideal 20 / (1 + ½) ms, efficiency ideal / 20."""
    measure = map_measure(np.full((10, 100), 0.02))
    even = run(StaticBalancer(), measure, 3)
    assert even[-1].imbalance == pytest.approx(1.0) and even[-1].efficiency == pytest.approx(1.0)
    slow = run(StaticBalancer(), measure, 3, {1: 1.0, 2: 2.0})
    assert slow[-1].node_ms == pytest.approx({1: 10.0, 2: 20.0})
    assert slow[-1].imbalance == pytest.approx(20.0 / 15.0)
    assert slow[-1].ideal_ms == pytest.approx(20.0 / 1.5)
    assert slow[-1].efficiency == pytest.approx((20.0 / 1.5) / 20.0)


# ------------------------------------------------------------------------------- frames in flight


def test_one_frame_in_flight_runs_frames_back_to_back() -> None:
    """One frame in flight: a frame starts when the last one is published, so frames are done at the
    running sum of frame times (10 ms each: 8 + 1 + 1 on node 1, (4 + ½ + ½) × 2 on node 2)."""
    measure = fixed_measure([Phases(8.0, 1.0, 1.0), Phases(4.0, 0.5, 0.5)])
    records = run(Fixed(halves()), measure, 3, {1: 1.0, 2: 2.0})
    assert [r.done_ms for r in records] == [10.0, 20.0, 30.0]
    assert [r.started_ms for r in records] == [0.0, 10.0, 20.0]


def test_push_two_in_flight_is_bound_by_the_slowest_node() -> None:
    """Two frames in flight: the light node (2 ms) runs a frame ahead but no further; frames are
    published every 10 ms, the heavy node's time."""
    records = run(Fixed(halves()), fixed_measure([Phases(10.0), Phases(2.0)]), 6, in_flight=2)
    assert [r.done_ms for r in records] == pytest.approx([10.0, 20.0, 30.0, 40.0, 50.0, 60.0])
    assert [r.started_ms for r in records] == pytest.approx([0.0, 2.0, 10.0, 20.0, 30.0, 40.0])
    assert summarize(records, skip=2)["frame_ms_pipelined"] == pytest.approx(10.0)


def test_pull_two_in_flight_fills_gaps_with_the_next_frame() -> None:
    """Pulled tiles of 6 and 2 ms on two equal nodes: one frame alone takes 6 ms (efficiency 4/6);
    with two in flight the node done early pulls from the next frame, so the period falls to the
    ideal 4 ms (frames are published in pairs, 2 ms apart every 8 ms; the window holds 5 pairs)."""
    measure = fixed_measure([Phases(6.0), Phases(2.0)])
    records = run(Fixed(halves(pull=True)), measure, 13, in_flight=2)
    assert [r.done_ms for r in records[:4]] == [6.0, 8.0, 14.0, 16.0]
    assert records[1].spans == ((2.0, 8.0, 6.0), (6.0, 8.0, 2.0))
    pipelined = summarize(records, skip=2)
    assert pipelined["efficiency_pipelined"] == pytest.approx(1.0)
    assert pipelined["frame_ms_pipelined"] == pytest.approx(4.0)
    single = run(Fixed(halves(pull=True)), measure, 13)
    assert [r.done_ms for r in single[:2]] == [6.0, 12.0]
    assert summarize(single, skip=2)["efficiency_pipelined"] == pytest.approx(4.0 / 6.0)


def test_rotate_pipelined_beats_its_one_frame_efficiency() -> None:
    """Tile rotation over two frames in flight keeps nodes busy: its pipelined efficiency is above
    its per-frame one, and static's stays bound by the slowest node."""
    cost = np.ones((60, 80))
    cost[:20, :30] = 20.0
    measure = map_measure(cost / cost.sum() * 30.0)

    def summary(balancer: Balancer) -> dict[str, float | int]:
        records, _ = run_path(balancer, measure, cameras(30), (80, 60), dict.fromkeys((1, 2, 3), 1.0))
        return summarize(records)

    rotate, static = summary(create_balancer("rotate")), summary(StaticBalancer())
    assert rotate["efficiency"] < rotate["efficiency_pipelined"] <= 1.0 + 1e-9
    assert rotate["efficiency_pipelined"] > 0.97
    assert static["efficiency_pipelined"] == pytest.approx(static["efficiency"])


def test_rotate_tiles_are_pulled_by_every_node() -> None:
    """rotate's pull list is handed out by the scheduler: every node works, the frame time is the
    slowest node's."""
    cost = np.ones((60, 80))
    cost[:20, :30] = 20.0
    records, _ = run_path(create_balancer("rotate"), map_measure(cost / cost.sum() * 30.0), cameras(20), (80, 60),
                          dict.fromkeys((1, 2, 3), 1.0), in_flight=1)
    assert all(r.partition.pull for r in records)
    last = records[-1]
    assert last.frame_ms == pytest.approx(max(last.node_ms.values())) and min(last.node_ms.values()) > 0.0
    assert last.efficiency == pytest.approx(last.work_ms / 3 / last.frame_ms)


def test_max_fps_spaces_frame_starts() -> None:
    """Frames of 10 ms paced at 50 frames/s start every 20 ms, and the balancer is told 20 ms
    passed between partitions."""
    fixed = Fixed(halves())
    records = run(fixed, fixed_measure([Phases(10.0), Phases(10.0)]), 4, in_flight=2, max_fps=50.0)
    assert [r.started_ms for r in records] == pytest.approx([0.0, 20.0, 40.0, 60.0])
    assert [r.done_ms for r in records] == pytest.approx([10.0, 30.0, 50.0, 70.0])
    assert [i.elapsed_ms for i in fixed.inputs] == pytest.approx([0.0, 20.0, 20.0, 20.0])


@pytest.mark.timeout(30)
def test_paced_frames_start_on_the_deadlines() -> None:
    """At 30 frames/s not every start deadline survives a round trip through ms (the 43rd,
    1.400000000000001 s, came back 1 ulp short, and the cluster ticked at that time forever, the
    scheduler not starting before its deadline): 100 frames start every 33.3 ms."""
    records = run(Fixed(halves()), fixed_measure([Phases(1.0), Phases(1.0)]), 100, max_fps=30.0)
    assert [r.started_ms for r in records] == pytest.approx([1000.0 * i / 30.0 for i in range(100)])


def test_a_cancelled_frame_leaves_the_node_queue() -> None:
    """The whole screen on node 1 (10 ms a frame), cameras every 4 ms, 2 frames in flight: frame 2
    waits behind frame 1 on node 1 when camera 2 comes, so the scheduler drops it and node 1 skips
    its tile: it renders frame 3 right after frame 1."""
    config = SchedulerConfig(size=SIZE, max_fps=1e9, still_codec=None, settle_frames=0)
    whole = Partition((Tile(Rect(0, 0, *SIZE), 1),))
    cluster = VirtualCluster(config, Fixed(whole), fixed_measure([Phases(10.0)]), {1: 1.0, 2: 1.0})
    records = cluster.run(cameras(3), dt_ms=4.0)
    assert [(r.frame_id, r.camera, r.done_ms) for r in records] == [(1, 0, 10.0), (3, 2, 20.0)]
    assert cluster.scheduler.frames_cancelled == 1
    assert records[1].spans == ((10.0, 20.0, 10.0),)


def test_a_cancel_keeps_the_tile_a_node_is_on() -> None:
    """A cancel reaching a node while it renders a tile of that frame drops only the queued ones (a
    real node cannot stop a draw): the tile it is on still ends, as its span says."""
    node = VirtualNode(1.0, deque([(5, 0, Rect(0, 0, 1, 1), Codec.RAW), (5, 1, Rect(1, 0, 1, 1), Codec.RAW),
                             (6, 0, Rect(0, 0, 1, 1), Codec.RAW)]), busy=True)
    VirtualCluster._cancel_queued(node, (5,))
    assert [(f, t) for f, t, _, _ in node.queue] == [(5, 0), (6, 0)]
    idle = VirtualNode(1.0, deque([(5, 1, Rect(1, 0, 1, 1), Codec.RAW)]))
    VirtualCluster._cancel_queued(idle, (5,))
    assert not idle.queue


# ------------------------------------------------------------------------------- balancer inputs


@pytest.mark.parametrize("in_flight,max_fps,behind", [(1, 30.0, 1), (2, math.inf, 2)])
def test_timings_weights_elapsed_and_groups(in_flight: int, max_fps: float, behind: int) -> None:
    """Paced at 30 frames/s with one frame in flight, frame f is partitioned with frame f-1's
    timings; as fast as it goes with two in flight, with frame f-2's (none before); every frame gets
    the weights, the virtual time since the last partition (0 on the first) and its camera's groups."""

    class Moving(Fixed):
        def partition(self, inputs: BalanceInput) -> Partition:
            self.inputs.append(inputs)
            cut = 30 + 10 * len(self.inputs)
            return Partition((Tile(Rect(0, 0, cut, 10), 1), Tile(Rect(cut, 0, 100 - cut, 10), 2)))

    recorder = Moving(halves())
    groups = [ProjectedGroups(np.array([[0.0, 0.0, float(f + 1), 1.0]]), np.ones(1)) for f in range(5)]
    records = run(recorder, map_measure(np.full((10, 100), 0.01)), 5, in_flight=in_flight, max_fps=max_fps,
                  weights={1: 1.0, 2: 2.0}, groups_at=groups.__getitem__)
    for frame, inputs in enumerate(recorder.inputs):
        source = frame - behind
        measured = records[source].partition.tiles if source >= 0 else ()
        assert [(t.rect, t.node_id) for t in inputs.timings] == [(t.rect, t.node_id) for t in measured]
        assert sum(t.busy_ms for t in inputs.timings) == pytest.approx(records[source].work_ms if measured else 0.0)
        assert inputs.previous == (records[frame - 1].partition if frame else None)
        started = [r.started_ms for r in records]
        assert inputs.elapsed_ms == pytest.approx(started[frame] - started[frame - 1] if frame else 0.0)
        assert inputs.weights == {1: 1.0, 2: 2.0} and inputs.groups is groups[frame]
    plain = run(StaticBalancer(), map_measure(np.ones((10, 100))), 2,
                groups_at=lambda camera: pytest.fail("groups projected for a balancer that does not use them"))
    assert len(plain) == 2


# ------------------------------------------------------------------------------- summary


def record(partition: Partition, done_ms: float, spans: tuple[tuple[float, float, float], ...] = (),
           frame_ms: float = 10.0, work_ms: float = 20.0, ideal_ms: float = 8.0, imbalance: float = 1.0,
           efficiency: float = 0.8, latency_ms: float = 0.0) -> FrameRecord:
    return FrameRecord(0, 0, partition, {1: 1.0, 2: 1.0}, frame_ms, work_ms, ideal_ms, imbalance, efficiency, 0.0,
                       done_ms, latency_ms, spans)


def test_summary_skips_frames_and_counts_repartitions() -> None:
    partitions = [halves(), halves(), Partition((Tile(Rect(0, 0, 40, 10), 1), Tile(Rect(40, 0, 60, 10), 2))),
                  Partition((Tile(Rect(40, 0, 60, 10), 2), Tile(Rect(0, 0, 40, 10), 1))), halves()]
    records = [record(p, 10.0 * i, imbalance=1.0 + i / 10, latency_ms=5.0 * i) for i, p in enumerate(partitions)]
    summary = summarize(records, skip=1)
    assert summary["frames"] == 4 and summary["repartitions"] == 2
    assert summary["imbalance_mean"] == pytest.approx(1.25) and summary["efficiency"] == pytest.approx(0.8)
    assert summary["imbalance_p95"] == pytest.approx(np.percentile([1.1, 1.2, 1.3, 1.4], 95))
    assert summary["latency_ms"] == pytest.approx(12.5)
    with pytest.raises(ValueError):
        summarize(records, skip=5)


def test_pipelined_window_arithmetic() -> None:
    """The window runs from the last left-out frame's publication (10 ms) to the last but one's
    (30 ms); each kept tile counts its part inside × its frame's ideal / work: frame 2's tiles
    (5–15 and 10–30 ms, ideal/work ½) give 2.5 + 10, frame 3's first (20–35 ms) 10/15 of 15 × ½ = 5,
    its second (30–40 ms) nothing."""
    records = [record(halves(), 10.0, ((0.0, 10.0, 10.0), (0.0, 10.0, 10.0)), 10.0, 20.0, 10.0),
               record(halves(), 30.0, ((5.0, 15.0, 10.0), (10.0, 30.0, 20.0)), 20.0, 30.0, 15.0),
               record(halves(), 40.0, ((20.0, 35.0, 15.0), (30.0, 40.0, 10.0)), 20.0, 25.0, 12.5)]
    pipelined = summarize(records, skip=1)
    assert pipelined["frame_ms_pipelined"] == pytest.approx(20.0)
    assert pipelined["efficiency_pipelined"] == pytest.approx((2.5 + 10.0 + 5.0) / 20.0)
    one_kept = summarize(records[:2], skip=1)
    assert np.isnan(one_kept["efficiency_pipelined"]) and np.isnan(one_kept["frame_ms_pipelined"])


def test_one_frame_in_flight_pipelined_is_the_per_frame_figure() -> None:
    measure = map_measure(np.full((10, 100), 0.02))
    summary = summarize(run(StaticBalancer(), measure, 12, {1: 1.0, 2: 2.0}), skip=2)
    assert summary["efficiency_pipelined"] == pytest.approx(summary["efficiency"])
    assert summary["frame_ms_pipelined"] == pytest.approx(summary["frame_ms"]) == pytest.approx(20.0)


# ------------------------------------------------------------------------------- bench.balance


def test_speedup_figures() -> None:
    """T1 40 ms, a frame every 12.5 ms on 4 nodes: speedup 3.2, parallel efficiency 0.8; slowdowns
    1, 1, 2, 4 can reach at most 2.75."""
    assert speedup_figures(40.0, 12.5, 4) == pytest.approx({"t1_ms": 40.0, "speedup": 3.2,
                                                             "parallel_efficiency": 0.8})
    assert math.isnan(speedup_figures(40.0, float("nan"), 4)["parallel_efficiency"])
    assert ideal_speedup([1.0, 1.0, 2.0, 4.0]) == pytest.approx(2.75)


def test_single_node_time_renders_the_whole_screen() -> None:
    class Timer:
        size = (64, 48)

        def __call__(self, frame: int, rects: Sequence[Rect]) -> list[Phases]:
            assert rects == [Rect(0, 0, 64, 48)]
            return [Phases(10.0 * frame, 1.0, 2.0)]

    assert single_node_ms(Timer(), [1, 2, 6]) == pytest.approx(30.0 + 3.0)


def test_an_animated_scene_plays_along_the_path_and_its_groups_move() -> None:
    from node.scene.loading import load_scene

    scene = load_scene("builtin:traffic")
    assert frame_states(scene, 3, None) == [None, None, None]
    states = frame_states(scene, 3, 0.5, start_time=2.0)
    assert [s.time for s in states if s is not None] == [2.0, 2.5, 3.0]
    camera = default_camera(scene.bounds, aspect=4 / 3)
    base = frame_groups(scene, camera, (320, 240), None)
    later = frame_groups(scene, camera, (320, 240), scene.state_at(7.0))
    assert base.weights.sum() == later.weights.sum() == scene.triangle_count    # every car stays in view
    assert not np.array_equal(base.boxes, later.boxes)                         # but the cars' load moved
    assert np.array_equal(frame_groups(scene, camera, (320, 240), scene.state_at(0.0)).boxes, base.boxes)


@pytest.mark.parametrize("argv,in_flight", [([], 2), (["--in-flight", "3"], 3), (["--lag", "0"], 1),
                                            (["--lag", "1"], 2)])
def test_lag_is_the_old_form_of_in_flight(argv: list[str], in_flight: int) -> None:
    parser = build_parser()
    args = parser.parse_args(["--scene", "builtin:spheres", "--path", "p.json", *argv])
    check_args(parser, args)
    assert args.in_flight == in_flight


@pytest.mark.parametrize("argv", [["--lag", "1", "--in-flight", "2"], ["--in-flight", "0"], ["--lag", "-1"]])
def test_in_flight_and_lag_are_checked(argv: list[str]) -> None:
    parser = build_parser()
    with pytest.raises(SystemExit):
        check_args(parser, parser.parse_args(["--scene", "builtin:spheres", "--path", "p.json", *argv]))


def test_a_param_goes_to_each_chosen_balancer_that_has_it() -> None:
    parser = build_parser()
    args = parser.parse_args(["--scene", "builtin:spheres", "--path", "p.json", "--balancers",
                              "rotate,rotate-predict,static", "--param", "tiles_per_node=4", "--param", "history=6",
                              "--param", "follow=false"])
    check_args(parser, args)
    assert args.balancer_params == {"rotate": {"tiles_per_node": 4},
                                    "rotate-predict": {"tiles_per_node": 4, "history": 6, "follow": False},
                                    "static": {}}
    assert create_balancer("rotate-predict", args.balancer_params["rotate-predict"]).params["tiles_per_node"] == 4
    for argv in (["--param", "history=6"], ["--param", "tiles_per_node"], ["--param", "tiles_per_node=four"]):
        with pytest.raises(SystemExit):   # no chosen balancer takes it; no value; not a number
            check_args(parser, parser.parse_args(["--scene", "builtin:spheres", "--path", "p.json",
                                                  "--balancers", "rotate", *argv]))


def test_pace() -> None:
    assert pace_fps("path", 40.0) == 25.0 and pace_fps("free", 40.0) == math.inf


@pytest.mark.gl
def test_benchmark_runs_end_to_end(tmp_path, monkeypatch) -> None:
    """14-frame orbit of the built-in spheres, 2 nodes, 160x120, one push and one pull balancer."""
    from bench.balance import main
    from node.scene.loading import load_scene

    monkeypatch.setenv("LP_NUM_THREADS", "0")  # main() sets it; restored after the test
    path = tmp_path / "orbit.json"
    path.write_text(json.dumps(make_path("orbit", load_scene("builtin:spheres").bounds, frames=14)))
    out, trace = tmp_path / "figures.json", tmp_path / "trace.jsonl"
    assert main(["--scene", "builtin:spheres", "--path", str(path), "--nodes", "2", "--size", "160x120",
                 "--balancers", "adaptive,rotate", "--speeds", "1,2", "--repeats", "1", "--json", str(out),
                 "--trace", str(trace)]) == 0
    figures = json.loads(out.read_text())
    frames = [json.loads(line) for line in trace.read_text().splitlines()]
    assert [f["balancer"] for f in frames] == ["adaptive"] * 14 + ["rotate"] * 14
    assert all(set(f["nodes"]) <= {"1", "2"} and f["nodes"] for f in frames)
    assert set(figures) == {"adaptive", "rotate", "meta"}
    for name in ("adaptive", "rotate"):
        row = figures[name]
        assert {"imbalance_mean", "imbalance_p95", "efficiency", "repartitions", "frames", "frame_ms", "work_ms",
                "efficiency_pipelined", "frame_ms_pipelined", "latency_ms", "frames_cancelled", "t1_ms", "speedup",
                "parallel_efficiency", "efficiency_worst", "efficiency_together", "efficiency_together_worst",
                "efficiency_sorted", "efficiency_best", "stagger_ms"} <= set(row)
        assert row["efficiency_worst"] <= row["efficiency"] <= row["efficiency_best"] + 1e-9
        assert max(row["efficiency_together"], row["efficiency_sorted"]) <= row["efficiency_best"] + 1e-9
        assert row["stagger_ms"] >= 0.0
        assert row["frames"] == 4 and row["frames_cancelled"] == 0
        assert 1.0 <= row["imbalance_mean"] <= row["imbalance_p95"]
        assert 0.0 < row["efficiency"] <= 1.0001 and 0.0 < row["efficiency_pipelined"] <= 1.0001
        assert 0 <= row["repartitions"] <= 4
        assert row["t1_ms"] > 0.0 and row["latency_ms"] >= row["frame_ms"] > 0.0
        assert row["speedup"] == pytest.approx(row["t1_ms"] / row["frame_ms_pipelined"])
        assert row["parallel_efficiency"] == pytest.approx(row["speedup"] / 2)
    meta = figures["meta"]
    assert meta["nodes"] == 2 and meta["size"] == [160, 120] and meta["speeds"] == [1.0, 2.0] and meta["lag"] == 1
    assert meta["in_flight"] == 2 and meta["pace"] == "free" and meta["max_fps"] is None
    assert meta["ideal_speedup"] == pytest.approx(1.5) and meta["t1_ms"] > 0.0
    assert meta["weights"]["1"] == pytest.approx(2.0) and meta["weights"]["2"] == pytest.approx(1.0)
    assert meta["lp_num_threads"] == 0 and meta["renderer"]
